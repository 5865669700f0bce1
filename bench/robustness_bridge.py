"""Attacks on the haptic UDP bridge, on loopback (prints JSON): the bridge part of the robustness bench.

:func:`bridge_attacks` opens a real :class:`~arsurf.haptics.udp_bridge.UdpBridgeDevice` on
127.0.0.1 (port 0, a hand-driven clock so the stale logic is deterministic), pins an operator
socket, then tries each attack ``n`` times with randomised content and reports, per kind, the
packets tried, accepted and dropped (by the bridge's own counters), whether the probe moved (the
bridge's ``read_state`` position left the operator's) and whether the attacker heard a FORCE.
The same is done against the reference client ``arsurf/haptics/client.py`` from a stand-in server
socket: per kind, FORCE packets tried, accepted, dropped, and whether any reached the hand (the
client's :meth:`poll` returned anything but the last valid force). Then the cost of the tag:
median and p99 of one POSE check (HMAC-SHA256) in microseconds.

:func:`flood` is the bridge under load: a 1 kHz servo loop (read the pose, command a spring force)
serves the reference client run as its own process at 1 kHz, while a keyless local process floods
the bridge port from 4 sockets with POSE-sized datagrams under a wrong key (bounded: at most
``--flood-packets`` datagrams in ``--flood-seconds`` minus 0.5 s; a small C flooder with
``sendmmsg`` when a C compiler is found, else a Python one). It reports the operator's poses accepted
over poses sent, the loop's ticks per second and the CPU time the loop thread and the bridge's
``read_state`` spent per tick (what the bridge costs, whatever else the machine runs), for
``--pairs`` alternated pairs of a run without and a run with the flood, then the flood against
the bridge with its kernel filter off (protocol version 2's behaviour). About 6 s per run.

The servo loop is the live loop's :class:`~arsurf.haptics.scheduler.Scheduler`;
``--realtime-priority P`` runs its thread under ``SCHED_FIFO`` where the OS grants it, as
``arsurf live`` and ``arsurf view --bridge-port`` run theirs by default (priority 10; 0: the
ordinary policy, their ``--no-realtime-priority``).

Run: ``python bench/robustness_bridge.py [--n 200] [--seed 0] [--flood-seconds 3] [--pairs 2]
[--realtime-priority 0]``
"""
from __future__ import annotations

import argparse
import hashlib
import hmac
import json
import math
import os
import platform
import socket
import struct
import sys
import time
import zlib

import numpy as np

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
sys.path.insert(0, ROOT)

from arsurf.haptics.udp_bridge import (  # noqa: E402
    POSE_SIZE,
    encode_challenge,
    UdpBridgeDevice,
    encode_force,
    encode_pose,
    encode_release,
    generate_key,
    save_key,
)

import arsurf.haptics.client as client_mod  # noqa: E402

LOOPBACK = "127.0.0.1"
OPERATOR_X = 0.01  # the operator's stylus x, m


class _Clock:
    def __init__(self):
        self.t = 1000.0

    def __call__(self):
        return self.t


def _udp() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind((LOOPBACK, 0))
    s.setblocking(False)
    return s


def _drain(sock) -> int:
    n = 0
    while True:
        try:
            sock.recv(4096)
            n += 1
        except BlockingIOError:
            return n


def _deliver(dev, sock, data) -> None:
    """Send ``data`` and poll until the bridge received it; 5 ms at most for a datagram the kernel
    filters (a sender other than the pinned peer never reaches the socket)."""
    before = dev.stats.received
    sock.sendto(data, dev.address)
    deadline = time.monotonic() + (1.0 if dev.peer is None or sock.getsockname() == dev.peer else 0.005)
    while dev.stats.received == before and time.monotonic() < deadline:
        dev.poll()


def _v1_pose(seq, t, x) -> bytes:
    body = struct.pack("<4sBBHId3d3d4dI", b"ARSH", 1, 1, 0, seq & 0xFFFFFFFF, t, x, 0.0, 0.0, *(math.nan,) * 3,
                       1.0, 0.0, 0.0, 0.0, 0)
    return body + struct.pack("<I", zlib.crc32(body))


def server_attacks(n: int, rng: np.random.Generator) -> dict:
    """Each attack ``n`` times against a bridge whose operator is pinned (then silent)."""
    key, wrong = generate_key(), generate_key()
    clock = _Clock()
    out = {}
    with UdpBridgeDevice(LOOPBACK, 0, key=key, clock=clock, stale_after=0.05, ramp_down=0.05) as dev:
        sid = dev.session
        op, attacker = _udp(), _udp()
        seq = [1]

        def op_pose(x=OPERATOR_X):
            seq[0] += 1
            clock.t += 0.001
            p = encode_pose(key, seq[0], clock.t, (x, 0.0, 0.0), session=sid)
            _deliver(dev, op, p)
            return p

        recorded = [op_pose() for _ in range(n)]  # the operator's traffic, as an eavesdropper saw it
        dev.command_force([0.0, 0.0, 1.0])
        _drain(op)
        release = encode_release(key, 10**15, 0.0, session=sid)  # a release the attacker forged... with the key

        def fresh_seq():
            return seq[0] + 1 + int(rng.integers(0, 10**6))

        def junk(lo, hi):
            return rng.integers(0, 256, int(rng.integers(lo, hi + 1)), dtype=np.uint8).tobytes()

        def flipped():
            p = bytearray(encode_pose(key, fresh_seq(), clock.t + 1.0, (0.5, 0.5, 0.5), session=sid))
            p[int(rng.integers(0, len(p)))] ^= 1 << int(rng.integers(0, 8))
            return bytes(p)

        kinds = {
            # (sender, packet factory, advance the clock past stale_after first)
            "hijack_with_key_after_operator_silent": ("attacker", lambda: encode_pose(
                key, fresh_seq(), clock.t, tuple(rng.uniform(-1, 1, 3)), session=sid), True),
            "hijack_without_key_after_operator_silent": ("attacker", lambda: encode_pose(
                wrong, fresh_seq(), clock.t, tuple(rng.uniform(-1, 1, 3)), session=sid), True),
            "forged_wrong_key_from_operator_address": ("operator", lambda: encode_pose(
                wrong, fresh_seq(), clock.t + 1.0, tuple(rng.uniform(-1, 1, 3)), session=sid), False),
            "bit_flipped_from_operator_address": ("operator", flipped, False),
            "replayed_operator_packets": ("operator", lambda: recorded[int(rng.integers(0, len(recorded)))], False),
            "replayed_from_attacker_address": ("attacker", lambda: recorded[int(rng.integers(0, len(recorded)))],
                                               False),
            "reordered_older_sequence": ("operator", lambda: encode_pose(
                key, int(rng.integers(0, 2)), clock.t + 1.0, (0.7, 0.0, 0.0), session=sid), False),
            "oversized": ("operator", lambda: encode_pose(key, fresh_seq(), clock.t + 1.0, (0.5, 0.0, 0.0), session=sid)
                          + junk(1, 4000), False),
            "truncated": ("operator", lambda: encode_pose(key, fresh_seq(), clock.t + 1.0, (0.5, 0.0, 0.0), session=sid)[
                :int(rng.integers(0, POSE_SIZE))], False),
            "random_junk_pose_sized": ("operator", lambda: junk(POSE_SIZE, POSE_SIZE), False),
            "protocol_v1_packets": ("operator", lambda: _v1_pose(fresh_seq(), clock.t + 1.0, 0.9), False),
            "release_from_attacker": ("attacker", lambda: release, False),
            "recorded_in_an_earlier_session": ("attacker", lambda: encode_pose(
                key, fresh_seq(), clock.t, tuple(rng.uniform(-1, 1, 3)), session=bytes(16)), True),
            "nonfinite_pose_with_key": ("operator", lambda: encode_pose(
                key, fresh_seq(), clock.t + 1.0, (math.nan, math.inf, 0.0), session=sid), False),
        }
        for kind, (who, make, silent) in kinds.items():
            sock = attacker if who == "attacker" else op
            before = dev.stats.as_dict()
            moved = False
            for _ in range(n):
                if silent:
                    clock.t += 0.06  # the operator has been silent longer than stale_after
                _deliver(dev, sock, make())
                s = dev.read_state()
                moved |= bool(s.position[0] != OPERATOR_X or s.position[1] != 0.0 or s.position[2] != 0.0)
                dev.command_force([0.0, 0.0, 1.0])
            after = dev.stats.as_dict()
            delta = {k: after[k] - before[k] for k in after if after[k] != before[k]}
            heard = _drain(attacker)
            _drain(op)
            out[kind] = {"tried": n, "accepted": delta.pop("accepted", 0), "dropped": delta.pop("dropped", 0),
                         "reasons": {k: v for k, v in delta.items() if k not in ("received", "sent")},
                         "probe_moved": moved, "forces_sent_to_attacker": heard,
                         "peer_still_operator": dev.peer == op.getsockname()}
            op_pose()  # the operator (back) at its place between kinds
        # the operator disappears: nobody takes over, the force it is sent fades to zero
        forces = []
        dropped0, accepted0 = dev.stats.dropped, dev.stats.accepted
        for _ in range(n):
            clock.t += 0.01
            _deliver(dev, attacker, encode_pose(key, fresh_seq(), clock.t, (0.3, 0.3, 0.3), session=sid))
            dev.read_state()
            dev.command_force([0.0, 0.0, 1.0])
            forces.append(dev.force_gain)
        out["operator_disappears"] = {"tried": n, "accepted": dev.stats.accepted - accepted0,
                                      "dropped": dev.stats.dropped - dropped0,
                                      "peer_still_operator": dev.peer == op.getsockname(),
                                      "probe_moved": bool(dev.read_state().position[0] != OPERATOR_X),
                                      "force_gain_after_0.1_s": forces[min(9, n - 1)], "force_gain_end": forces[-1],
                                      "forces_sent_to_attacker": _drain(attacker)}
        out["bridge_stats"] = dev.stats.as_dict()
        op.close()
        attacker.close()
    return out


def client_attacks(n: int, rng: np.random.Generator) -> dict:
    """Each bad FORCE ``n`` times at the reference client; does any reach the hand?"""
    key, wrong = generate_key(), generate_key()
    srv, attacker = _udp(), _udp()
    clock = _Clock()
    c = client_mod.HapticClient(LOOPBACK, srv.getsockname()[1], key, max_force=7.9, timeout=0.1, clock=clock)
    c.send_pose((0.0, 0.0, 0.0))  # no session yet: a HELLO
    sid = bytes(range(16))
    hello_seq = c.seq
    deadline = time.monotonic() + 1.0
    while c.session is None and time.monotonic() < deadline:
        srv.sendto(encode_challenge(key, 99, hello_seq, sid), c.sock.getsockname())
        time.sleep(1e-3)
        c.poll()
    c.send_pose((0.0, 0.0, 0.0))
    ack = c.seq
    good = (0.0, 0.0, 1.0)
    seq = [100]

    def to_client(sock, data):
        before = c.stats["received"]
        sock.sendto(data, c.sock.getsockname())
        deadline = time.monotonic() + 1.0
        f = c.poll()
        while c.stats["received"] == before and time.monotonic() < deadline:
            f = c.poll()
        return f

    def nxt():
        seq[0] += 1
        return seq[0]

    def force(f, k=key, a=None, s=None, t=0.0):
        return encode_force(k, nxt() if s is None else s, ack if a is None else a, t, 0.0, f, session=sid)

    recorded = [force(good) for _ in range(4)]
    for p in recorded:
        to_client(srv, p)

    def flipped():
        p = bytearray(force(tuple(rng.uniform(-5, 5, 3))))
        p[int(rng.integers(0, len(p)))] ^= 1 << int(rng.integers(0, 8))
        return bytes(p)

    def v1():
        b = struct.pack("<4sBBHIIdd3d", b"ARSH", 1, 2, 0, nxt() & 0xFFFFFFFF, ack & 0xFFFFFFFF, 0.0, 0.0, 0.0, 0.0, 5.0)
        return b + struct.pack("<I", zlib.crc32(b))

    kinds = {
        "nan_force": ("server", lambda: force((math.nan, 0.0, 1.0))),
        "inf_force": ("server", lambda: force((0.0, -math.inf, 0.0))),
        "huge_force_1e6_N": ("server", lambda: force(tuple(rng.normal(0, 1, 3) * 1e6))),
        "just_over_limit": ("server", lambda: force((0.0, 0.0, 7.9 * (1 + 1e-6)))),
        "forged_wrong_key": ("server", lambda: force(tuple(rng.uniform(-5, 5, 3)), k=wrong)),
        "bit_flipped": ("server", flipped),
        "replayed_latest_valid": ("server", lambda: recorded[-1]),
        "replayed_older_valid": ("server", lambda: recorded[int(rng.integers(0, len(recorded) - 1))]),
        "reordered_older_sequence": ("server", lambda: force((0.0, 0.0, 3.0), s=int(rng.integers(0, 100)))),
        "foreign_sender_with_key": ("attacker", lambda: force((0.0, 0.0, 5.0))),
        "ack_of_an_earlier_run": ("server", lambda: force((0.0, 0.0, 5.0), a=c.first_seq - 1 - int(
            rng.integers(0, 10**6)))),
        "protocol_v1_packets": ("server", v1),
        "force_of_another_session": ("server", lambda: encode_force(key, nxt(), ack, 0.0, 0.0, (0.0, 0.0, 5.0),
                                                                   session=bytes(16))),
        "truncated": ("server", lambda: force(good)[:int(rng.integers(0, 112))]),
        "oversized": ("server", lambda: force(good) + bytes(int(rng.integers(1, 3000)))),
    }
    out = {}
    for kind, (who, make) in kinds.items():
        sock = attacker if who == "attacker" else srv
        before = dict(c.stats)
        reached = False
        for _ in range(n):
            f = to_client(sock, make())
            reached |= f != good
        delta = {k: c.stats[k] - before[k] for k in c.stats if c.stats[k] != before[k]}
        out[kind] = {"tried": n, "accepted": delta.pop("accepted", 0),
                     "dropped": sum(v for k, v in delta.items() if k != "received"),
                     "reasons": {k: v for k, v in delta.items() if k != "received"}, "reached_hand": reached}
        recorded.append(force(good))  # a valid one keeps the client's force fresh between kinds
        to_client(srv, recorded[-1])
    clock.t += 0.2  # the server disappears: the hand gets zero after the timeout
    out["server_disappears"] = {"force_after_timeout": list(c.poll())}
    out["client_stats"] = dict(c.stats)
    c.close()
    srv.close()
    attacker.close()
    return out


def tag_cost(n: int = 20000) -> dict:
    """Median and p99 time of one HMAC-SHA256 check of a POSE, microseconds."""
    key = generate_key()
    pkt = encode_pose(key, 1, 0.0, (0.0, 0.0, 0.0), session=bytes(16))
    mv = memoryview(pkt)
    ts = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter_ns()
        hmac.compare_digest(hmac.new(key, mv[:124], hashlib.sha256).digest(), mv[124:])
        ts[i] = time.perf_counter_ns() - t0
    crc = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter_ns()
        zlib.crc32(mv[:124])
        crc[i] = time.perf_counter_ns() - t0
    return {"hmac_check_median_us": float(np.median(ts)) / 1e3, "hmac_check_p99_us": float(np.percentile(ts, 99)) / 1e3,
            "crc32_v1_median_us": float(np.median(crc)) / 1e3,
            "ratio_hmac_over_crc32": float(np.median(ts) / max(np.median(crc), 1.0))}


_FLOODER = r"""
import socket, sys, time
port, seconds, limit, pkt = int(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3]), bytes.fromhex(sys.argv[4])
socks = []
for _ in range(4):
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.setblocking(False)
    socks.append(s)
addr, sent, tried, t0 = ("127.0.0.1", port), 0, 0, time.perf_counter()
while tried < limit and time.perf_counter() - t0 < seconds:
    for s in socks:
        for _ in range(64):
            tried += 1
            try:
                s.sendto(pkt, addr)
                sent += 1
            except OSError:  # buffer full, or an ICMP error reported on the socket
                pass
print(sent, tried, time.perf_counter() - t0)
"""


_FLOODER_C = r"""
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>
static double now(void) { struct timespec t; clock_gettime(CLOCK_MONOTONIC, &t); return t.tv_sec + 1e-9 * t.tv_nsec; }
int main(int argc, char **argv) {  /* port seconds limit hexpacket: 4 sockets, sendmmsg 64 at a time */
    int port = atoi(argv[1]); double seconds = atof(argv[2]); long long limit = atoll(argv[3]);
    size_t n = strlen(argv[4]) / 2; unsigned char pkt[2048];
    if (n > sizeof pkt) return 2;
    for (size_t i = 0; i < n; i++) sscanf(argv[4] + 2 * i, "%2hhx", &pkt[i]);
    struct sockaddr_in to = {0}; to.sin_family = AF_INET; to.sin_port = htons(port);
    to.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    int socks[4];
    for (int k = 0; k < 4; k++) { socks[k] = socket(AF_INET, SOCK_DGRAM | SOCK_NONBLOCK, 0); if (socks[k] < 0) return 2; }
    struct iovec iov = {pkt, n}; struct mmsghdr msgs[64]; memset(msgs, 0, sizeof msgs);
    for (int i = 0; i < 64; i++) { msgs[i].msg_hdr.msg_name = &to; msgs[i].msg_hdr.msg_namelen = sizeof to;
                                   msgs[i].msg_hdr.msg_iov = &iov; msgs[i].msg_hdr.msg_iovlen = 1; }
    long long sent = 0, tried = 0; double t0 = now();
    while (tried < limit && now() - t0 < seconds)
        for (int k = 0; k < 4; k++) { int r = sendmmsg(socks[k], msgs, 64, 0); tried += 64; if (r > 0) sent += r; }
    printf("%lld %lld %f\n", sent, tried, now() - t0);
    return 0;
}
"""


def _flooder(tmp: str) -> list[str]:
    """The flooder's command: the C one (sendmmsg, several times the Python one's rate) when a C
    compiler is found, else the Python one."""
    import shutil
    import subprocess

    cc = shutil.which("cc") or shutil.which("gcc")
    if cc:
        src, exe = os.path.join(tmp, "flood.c"), os.path.join(tmp, "flood")
        with open(src, "w") as fh:
            fh.write(_FLOODER_C)
        if subprocess.run([cc, "-O2", "-o", exe, src], capture_output=True).returncode == 0:
            return [exe]
    return [sys.executable, "-c", _FLOODER]


def _serve(dev, stop, ticks, rate, reads, cpu, priority=0, granted=None):
    """A 1 kHz servo loop, the live loop's :class:`~arsurf.haptics.scheduler.Scheduler` (its
    pacing, policy and statistics): read the pose, command a spring force. ``cpu`` gets the
    loop thread's CPU time at each tick (what the loop itself spent, whatever else the machine
    runs). ``priority``: ``SCHED_FIFO`` for the loop thread where the OS grants it, as ``arsurf
    live`` and ``arsurf view --bridge-port`` give their loop by default (the priority granted and
    the loop's timing go to ``granted``)."""
    from arsurf.haptics.scheduler import Scheduler

    def step(state, inputs, dt):
        cpu.append(time.thread_time())
        t_read, c_read = time.perf_counter(), time.thread_time()
        s = dev.read_state()  # the bridge's own work: drain the socket, parse, check
        reads.append((time.perf_counter() - t_read, time.thread_time() - c_read))
        dev.command_force(-100.0 * s.position)
        ticks.append(time.perf_counter())

    sched = Scheduler(step, None, rate=rate, priority=priority).start()
    stop.wait()
    stats = sched.stop()
    if granted is not None:
        granted.append(stats.realtime_priority)
        granted.append(stats)


def flood_run(flood: bool, seconds: float = 3.0, flood_packets: int = 3_000_000, rate: float = 1000.0,
              kernel_filter: bool = True, priority: int = 0) -> dict:
    """One served session of ``seconds`` with the reference client at ``rate``, flooded or not.

    ``kernel_filter=False`` is the ablation: the pinned peer is not connected and 256
    datagrams are drained per tick, as protocol version 2 did (everything else as shipped)."""
    import subprocess
    import tempfile
    import threading

    key = generate_key()
    with tempfile.TemporaryDirectory() as d, UdpBridgeDevice(
            LOOPBACK, 0, key=key, max_packets_per_read=64 if kernel_filter else 256) as dev:
        if not kernel_filter:
            dev._pin = lambda addr: setattr(dev, "peer", addr)  # no connect(): every sender queues
            sock_send = dev._transmit

            def transmit(pkt, addr):  # an unconnected socket sends with sendto
                peer, dev.peer = dev.peer, None
                try:
                    sock_send(pkt, addr)
                finally:
                    dev.peer = peer
            dev._transmit = transmit
        kf = save_key(os.path.join(d, "k"), key)
        port = dev.address[1]
        stop, ticks, reads, cpu, granted = threading.Event(), [], [], [], []
        th = threading.Thread(target=_serve, args=(dev, stop, ticks, rate, reads, cpu, priority, granted), daemon=True)
        th.start()
        client = subprocess.Popen([sys.executable, "-m", "arsurf.haptics.client", "--port", str(port), "--key-file",
                                   kf, "--rate", str(rate), "--duration", str(seconds), "--radius", "0.01"],
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
        deadline = time.monotonic() + 10.0
        while dev.peer is None and time.monotonic() < deadline:
            time.sleep(0.001)
        t_pin = time.perf_counter()
        accepted0 = dev.stats.accepted
        flooded = {"packets": 0, "seconds": 0.0}
        if flood:
            junk = encode_pose(generate_key(), 1, 0.0, (0.3, 0.3, 0.3), session=bytes(16))  # keyless: a wrong key
            cmd = _flooder(d)
            out = subprocess.run([*cmd, str(port), str(seconds - 0.5), str(flood_packets), junk.hex()],
                                 capture_output=True, text=True, timeout=seconds + 30)
            n, tried, dt = out.stdout.split()
            flooded = {"flooder": "C, sendmmsg" if len(cmd) == 1 else "Python", "packets": int(n), "tried": int(tried),
                       "seconds": float(dt), "packets_per_s": int(n) / float(dt)}
        out, err = client.communicate(timeout=seconds + 30)
        t_end = time.perf_counter()
        stop.set()
        th.join(2.0)
        summary = json.loads(out)
        ticks, cpu = ticks[:len(cpu)], cpu[:len(ticks)]
        inside = [i for i, t in enumerate(ticks) if t_pin <= t <= t_end]
        window = [ticks[i] for i in inside]
        cpu_per_tick = ((cpu[inside[-1]] - cpu[inside[0]]) / (len(inside) - 1)) if len(inside) > 1 else 0.0
        in_window = [r for t, r in zip(ticks, reads) if t_pin <= t <= t_end] or [(0.0, 0.0)]
        read_cpu = [c for _, c in in_window]
        in_window = [w for w, _ in in_window]
        gaps = np.diff(window) if len(window) > 1 else np.array([0.0])
        return {
            "flood": flooded,
            "operator_poses_sent": summary["poses_sent"],
            "operator_poses_accepted": dev.stats.accepted - accepted0 + 1,  # + the pose that pinned it
            "operator_accepted_fraction": (dev.stats.accepted - accepted0 + 1) / max(1, summary["poses_sent"]),
            "operator_replies_accepted_with_rtt": summary["replies_with_rtt"],
            "loop_ticks_per_s": (len(window) - 1) / (window[-1] - window[0]) if len(window) > 1 else 0.0,
            "loop_rate_fraction": ((len(window) - 1) / (window[-1] - window[0]) / rate) if len(window) > 1 else 0.0,
            "loop_tick_gap_p99_ms": float(np.percentile(gaps, 99)) * 1e3,
            "loop_tick_gap_max_ms": float(gaps.max()) * 1e3,
            "loop_cpu_per_tick_us": cpu_per_tick * 1e6,
            "loop_realtime_priority": granted[0] if granted else 0,
            "loop_longest_gap_ms": granted[1].longest_gap * 1e3 if len(granted) > 1 else None,
            "loop_awake_max": granted[1].awake_max if len(granted) > 1 else None,
            "bridge_read_state_median_us": float(np.median(in_window)) * 1e6,
            "bridge_read_state_p99_us": float(np.percentile(in_window, 99)) * 1e6,
            "bridge_read_state_cpu_mean_us": float(np.mean(read_cpu)) * 1e6,
            "machine_load_average_1min": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
            "bridge_stats": dev.stats.as_dict(),
        }


def flood(seconds: float = 3.0, flood_packets: int = 3_000_000, pairs: int = 2, priority: int = 0) -> dict:
    """The bridge with and without a keyless local flood, side by side: ``pairs`` quiet/flooded
    pairs run alternately (so a change of the machine's load hits both alike), then the ablation.
    The kept fractions are the medians over the pairs of flooded over quiet."""
    runs = []
    for _ in range(pairs):
        runs.append((flood_run(False, seconds, flood_packets, priority=priority),
                     flood_run(True, seconds, flood_packets, priority=priority)))
    ablation = flood_run(True, seconds, flood_packets, kernel_filter=False, priority=priority)

    def kept(key):
        return [loud[key] / max(1e-12, quiet[key]) for quiet, loud in runs]

    poses, rate, cpu = kept("operator_accepted_fraction"), kept("loop_ticks_per_s"), kept("loop_cpu_per_tick_us")
    read_cpu = kept("bridge_read_state_cpu_mean_us")
    return {"pairs": [{"no_flood": q, "flood": f} for q, f in runs],
            "flood_without_kernel_filter_v2_behaviour": ablation,
            "operator_poses_kept_under_flood": float(np.median(poses)), "operator_poses_kept_per_pair": poses,
            "loop_rate_kept_under_flood": float(np.median(rate)), "loop_rate_kept_per_pair": rate,
            "loop_cpu_per_tick_ratio_under_flood": float(np.median(cpu)), "loop_cpu_per_tick_ratio_per_pair": cpu,
            "bridge_read_state_cpu_ratio_under_flood": float(np.median(read_cpu)),
            "bridge_read_state_cpu_ratio_per_pair": read_cpu,
            "ablation_operator_poses_kept": ablation["operator_accepted_fraction"] / max(
                1e-12, float(np.median([q["operator_accepted_fraction"] for q, _ in runs]))),
            "ablation_loop_rate_kept": ablation["loop_ticks_per_s"] / max(
                1e-12, float(np.median([q["loop_ticks_per_s"] for q, _ in runs])))}


def bridge_attacks(n: int = 200, seed: int = 0, echo: bool = True, flood_seconds: float = 3.0, pairs: int = 2,
                   priority: int = 0, flood_packets: int = 3_000_000) -> dict:
    """Run every attack ``n`` times on the bridge and on the reference client, and the flood
    (:func:`flood`, skipped with ``flood_seconds=0``); print and return JSON."""
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    server = server_attacks(n, rng)
    client = client_attacks(n, rng)
    flooded = flood(flood_seconds, flood_packets, pairs=pairs, priority=priority) if flood_seconds > 0 else None
    report = {
        "benchmark": "robustness_bridge",
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count(), "platform": platform.platform()},
        "attempts_per_kind": n,
        "server": server,
        "client": client,
        "summary": {
            "server_attacks_accepted": sum(v.get("accepted", 0) for k, v in server.items() if k != "bridge_stats"),
            "probe_ever_moved": any(v.get("probe_moved", False) for k, v in server.items() if k != "bridge_stats"),
            "forces_sent_to_attackers": sum(v.get("forces_sent_to_attacker", 0) for k, v in server.items()
                                            if k != "bridge_stats"),
            "client_attacks_accepted": sum(v.get("accepted", 0) for k, v in client.items()
                                           if isinstance(v, dict) and "tried" in v),
            "bad_force_ever_reached_hand": any(v.get("reached_hand", False) for v in client.values()
                                               if isinstance(v, dict)),
        },
        "tag_cost": tag_cost(),
        "flood": flooded,
    }
    report["wall_s"] = time.perf_counter() - t0
    if echo:
        print(json.dumps(report, indent=2))
    return report


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=200, help="attempts per attack kind")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--flood-seconds", type=float, default=3.0, help="length of each flood run, s (0: no flood)")
    ap.add_argument("--pairs", type=int, default=2, help="quiet/flooded run pairs (alternated)")
    ap.add_argument("--flood-packets", type=int, default=3_000_000, help="at most this many flood datagrams per run")
    ap.add_argument("--realtime-priority", type=int, default=0, metavar="P",
                    help="SCHED_FIFO priority of the flood runs' servo thread where the OS grants it (0: none)")
    args = ap.parse_args(argv)
    bridge_attacks(args.n, args.seed, flood_seconds=args.flood_seconds, pairs=args.pairs,
                   priority=args.realtime_priority, flood_packets=args.flood_packets)
    return 0


if __name__ == "__main__":
    sys.exit(main())
