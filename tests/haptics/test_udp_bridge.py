"""UDP bridge on loopback: the protocol (v3, HMAC-SHA256, a session id per open), good and bad
packets, a pinned peer the kernel filters for, replays within and across sessions, stale input, the
reference client's checks on FORCE and CHALLENGE packets, keys and the CLI."""
from __future__ import annotations

import hashlib
import hmac
import json
import math
import os
import re
import socket
import stat
import struct
import threading
import time
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from arsurf.errors import HapticsError
from arsurf.haptics.device import DeviceInfo
from arsurf.haptics.udp_bridge import (
    CHALLENGE_SIZE,
    FORCE_SIZE,
    HELLO_SIZE,
    POSE_SIZE,
    RELEASE_SIZE,
    UdpBridgeDevice,
    decode_challenge,
    decode_force,
    decode_pose,
    encode_challenge,
    encode_force,
    encode_hello,
    encode_pose,
    encode_release,
    generate_key,
    is_loopback,
    key_from_hex,
    load_key,
    save_key,
)

ROOT = Path(__file__).resolve().parents[2]
import arsurf.haptics.client as client_mod  # noqa: E402  (the reference client, standard library only)
from tests.support.bridge_keys import _planted_key_files  # noqa: E402

LOOPBACK = "127.0.0.1"
KEY = bytes(range(32))
OTHER_KEY = bytes(range(100, 132))
SID = bytes(range(0xF0, 0x100))  # the session id the tests give an opened bridge (normally random)


class FakeClock:
    """A clock the test advances by hand (the bridge's stale/ramp logic becomes deterministic)."""

    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


@pytest.fixture
def clock():
    return FakeClock()


@pytest.fixture
def bridge(clock):
    dev = UdpBridgeDevice(LOOPBACK, 0, key=KEY, clock=clock, stale_after=0.045, ramp_down=0.05, ramp_up=0.1)
    dev.open()
    dev.session = SID
    yield dev
    dev.close()


def _udp():
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind((LOOPBACK, 0))
    s.settimeout(1.0)
    return s


@pytest.fixture
def client():
    s = _udp()
    yield s
    s.close()


@pytest.fixture
def intruder():
    s = _udp()
    yield s
    s.close()


def deliver(dev, sock, data):
    """Send ``data`` to the bridge and poll until it has been received (bounded: 1 s)."""
    before = dev.stats.received
    sock.sendto(data, dev.address)
    deadline = time.monotonic() + 1.0
    while dev.stats.received == before:
        dev.poll()
        if time.monotonic() > deadline:
            raise AssertionError("the datagram never arrived on loopback")
        time.sleep(1e-4)


def pose(seq, t, x=0.0, key=KEY, session=SID, **kw):
    return encode_pose(key, seq=seq, t=t, position=(x, 0.0, 0.0), session=session, **kw)


def release(seq, t, key=KEY, session=SID):
    return encode_release(key, seq, t, session=session)


def filtered(dev, sock, data, op):
    """Send ``data`` from ``sock`` and assert the kernel never delivered it: the operator socket
    ``op`` says HELLO right after, and that HELLO is the only datagram the bridge receives."""
    before, hellos = dev.stats.received, dev.stats.hellos
    sock.sendto(data, dev.address)
    deliver(dev, op, encode_hello(KEY, 10**15 + before, 0.0))
    assert dev.stats.received == before + 1 and dev.stats.hellos == hellos + 1
    op.recv(256)  # the CHALLENGE


def nothing_pending(sock) -> bool:
    """No datagram waiting on ``sock`` (loopback delivers at once: the caller first made sure a
    datagram sent after the ones it worries about has arrived elsewhere)."""
    sock.setblocking(False)
    try:
        sock.recv(4096)
    except BlockingIOError:
        return True
    finally:
        sock.settimeout(1.0)
    return False


def v1_pose(seq, t, x):
    """A version-1 POSE (108 bytes, CRC-32 last) as the old protocol defined it."""
    body = struct.pack("<4sBBHId3d3d4dI", b"ARSH", 1, 1, 0, seq, t, x, 0.0, 0.0, *(math.nan,) * 3,
                       1.0, 0.0, 0.0, 0.0, 0)
    return body + struct.pack("<I", zlib.crc32(body))


# ---------------------------------------------------------------------------------------------
# the layout
# ---------------------------------------------------------------------------------------------
def test_packet_layout_matches_the_documented_offsets():
    pkt = encode_pose(KEY, seq=0x0102030405060708, t=1.5, position=(1.0, 2.0, 3.0), velocity=(4.0, 5.0, 6.0),
                      quaternion=(0.5, 0.5, 0.5, 0.5), buttons=0xA5, session=SID)
    assert len(pkt) == POSE_SIZE == 156
    assert pkt[0:4] == b"ARSH" and pkt[4] == 3 and pkt[5] == 1 and pkt[6:8] == b"\0\0"
    assert struct.unpack_from("<Q", pkt, 8)[0] == 0x0102030405060708
    assert pkt[16:32] == SID
    assert struct.unpack_from("<d", pkt, 32)[0] == 1.5
    assert struct.unpack_from("<3d", pkt, 40) == (1.0, 2.0, 3.0)
    assert struct.unpack_from("<3d", pkt, 64) == (4.0, 5.0, 6.0)
    assert struct.unpack_from("<4d", pkt, 88) == (0.5, 0.5, 0.5, 0.5)
    assert struct.unpack_from("<I", pkt, 120)[0] == 0xA5
    assert pkt[124:] == hmac.new(KEY, pkt[:124], hashlib.sha256).digest()
    f = encode_force(KEY, seq=2**40 + 9, ack=2**40 + 8, t=2.0, echo=1.5, force=(0.1, 0.2, 0.3), flags=2, session=SID)
    assert len(f) == FORCE_SIZE == 112
    assert f[0:4] == b"ARSH" and f[4] == 3 and f[5] == 2 and struct.unpack_from("<H", f, 6)[0] == 2
    assert struct.unpack_from("<Q", f, 8)[0] == 2**40 + 9 and f[16:32] == SID
    assert struct.unpack_from("<Qdd3d", f, 32) == (2**40 + 8, 2.0, 1.5, 0.1, 0.2, 0.3)
    assert f[80:] == hmac.new(KEY, f[:80], hashlib.sha256).digest()
    r = encode_release(KEY, seq=5, t=0.25, session=SID)
    assert len(r) == RELEASE_SIZE == 72 and r[5] == 3 and struct.unpack_from("<Q", r, 8)[0] == 5
    assert r[16:32] == SID and struct.unpack_from("<d", r, 32)[0] == 0.25
    assert r[40:] == hmac.new(KEY, r[:40], hashlib.sha256).digest()
    h = encode_hello(KEY, seq=6, t=0.5)
    assert len(h) == HELLO_SIZE == 72 and h[5] == 4 and h[16:32] == bytes(16) and struct.unpack_from("<d", h, 32)[0] == 0.5
    assert h[40:] == hmac.new(KEY, h[:40], hashlib.sha256).digest()
    c = encode_challenge(KEY, seq=7, ack=6, session=SID)
    assert len(c) == CHALLENGE_SIZE == HELLO_SIZE and c[5] == 5 and c[16:32] == SID
    assert struct.unpack_from("<Q", c, 32)[0] == 6 and c[40:] == hmac.new(KEY, c[:40], hashlib.sha256).digest()
    with pytest.raises(HapticsError, match="sequence number must be in 0..2"):
        encode_pose(KEY, 2**64, 0.0, (0, 0, 0), session=SID)
    with pytest.raises(HapticsError, match="session id must be 16 bytes"):
        encode_pose(KEY, 1, 0.0, (0, 0, 0), session=b"short")


def _doc_vectors():
    text = (ROOT / "docs" / "bridge-protocol.rst").read_text()
    found: dict[str, bytes] = {}
    for name, part, data in re.findall(r"^\s*(key|session|\w+)(?:\.(body|tag))?\s+(?:[0-9a-f]{4}:)?\s*([0-9a-f ]+)$", text,
                                       re.MULTILINE):
        k = name if not part else f"{name}.{part}"
        found[k] = found.get(k, b"") + bytes.fromhex(data.replace(" ", ""))
    return found


def test_the_documented_test_vector():
    """docs/bridge-protocol.rst's vector (what a C client checks itself against) is what both
    Python implementations produce, and its tags are plain HMAC-SHA256 over the body."""
    v = _doc_vectors()
    key, sid = v["key"], v["session"]
    assert key == bytes(range(32)) and sid == SID
    for name in ("hello", "challenge", "pose", "force", "release"):
        assert v[f"{name}.tag"] == hmac.new(key, v[f"{name}.body"], hashlib.sha256).digest(), name
    h = v["hello.body"] + v["hello.tag"]
    assert encode_hello(key, 1, 0.25) == h == client_mod.encode_hello(key, 1, 0.25)
    c = v["challenge.body"] + v["challenge.tag"]
    assert encode_challenge(key, 2, 1, sid) == c and decode_challenge(key, c) == {"seq": 2, "session": sid, "ack": 1}
    p = v["pose.body"] + v["pose.tag"]
    args = (2, 0.5, (0.001, -0.002, 0.003), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), 1)
    assert encode_pose(key, *args, session=sid) == p == client_mod.encode_pose(key, *args, session=sid)
    f = v["force.body"] + v["force.tag"]
    assert encode_force(key, 3, 2, 1.25, 0.5, (0.0, 0.0, 1.5), 0, session=sid) == f
    assert client_mod.decode_force(key, f)["force"] == (0.0, 0.0, 1.5)
    r = v["release.body"] + v["release.tag"]
    assert encode_release(key, 3, 0.75, session=sid) == r == client_mod.encode_release(key, 3, 0.75, session=sid)


@settings(max_examples=60, deadline=None)
@given(seq=st.integers(0, 2**64 - 1), t=st.floats(allow_nan=False), buttons=st.integers(0, 2**32 - 1),
       pos=st.lists(st.floats(allow_nan=False), min_size=3, max_size=3),
       vel=st.lists(st.floats(), min_size=3, max_size=3))
def test_reference_client_and_bridge_agree_byte_for_byte(seq, t, buttons, pos, vel):
    a = encode_pose(KEY, seq, t, pos, vel, (1.0, 0.0, 0.0, 0.0), buttons, session=SID)
    b = client_mod.encode_pose(KEY, seq, t, pos, vel, (1.0, 0.0, 0.0, 0.0), buttons, session=SID)
    assert a == b
    d = decode_pose(KEY, a)
    assert d["seq"] == seq and d["buttons"] == buttons and d["flags"] == 0 and d["session"] == SID
    assert decode_pose(OTHER_KEY, a) is None
    assert encode_hello(KEY, seq, t) == client_mod.encode_hello(KEY, seq, t)
    f = encode_force(KEY, seq, seq ^ 1, t, t, pos, flags=3, session=SID)
    assert client_mod.decode_force(KEY, f) == decode_force(KEY, f)
    assert client_mod.decode_force(OTHER_KEY, f) is None and decode_force(OTHER_KEY, f) is None


# ---------------------------------------------------------------------------------------------
# good packets
# ---------------------------------------------------------------------------------------------
def test_poses_in_forces_out_on_loopback(bridge, client, clock):
    deliver(bridge, client, pose(1, 0.0, 0.01, velocity=(0.1, 0.0, 0.0), buttons=1, quaternion=(2.0, 0, 0, 0)))
    s = bridge.read_state()
    np.testing.assert_array_equal(s.position, [0.01, 0.0, 0.0])
    np.testing.assert_array_equal(s.velocity, [0.1, 0.0, 0.0])
    assert s.buttons == 1 and s.timestamp == clock.t and bridge.input_age() == 0.0
    assert bridge.peer == client.getsockname() and bridge.stats.pins == 1
    np.testing.assert_array_equal(bridge.orientation, [1.0, 0, 0, 0])  # normalised
    bridge.command_force([0.0, 0.5, 0.0])
    reply = decode_force(KEY, client.recv(256))
    assert reply["ack"] == 1 and reply["force"] == (0.0, 0.5, 0.0) and reply["echo"] == 0.0 and reply["flags"] == 0
    first_seq = reply["seq"]
    # without velocity the bridge differentiates positions with the client timestamps
    clock.t += 0.001
    deliver(bridge, client, pose(2, 0.002, 0.0102))
    s = bridge.read_state()
    np.testing.assert_allclose(s.velocity, [0.1, 0.0, 0.0], rtol=1e-9)
    # a force above the device limit is clamped and flagged in the reply
    bridge.command_force([0.0, 0.0, 100.0])
    reply = decode_force(KEY, client.recv(256))
    assert reply["force"][2] == pytest.approx(7.9) and reply["flags"] & 4 and reply["seq"] == first_seq + 1


def test_sequence_numbers_are_64_bit_and_do_not_wrap(bridge, client, clock):
    deliver(bridge, client, pose(2**32 - 1, 0.0))
    clock.t += 0.001
    deliver(bridge, client, pose(2**32, 0.001, 0.001))
    assert bridge.stats.accepted == 2 and bridge.read_state().position[0] == 0.001
    clock.t += 0.001
    deliver(bridge, client, pose(0, 0.002, 0.5))  # would be "after 2**32 - 1" modulo 2**32; not here
    assert bridge.stats.accepted == 2 and bridge.stats.out_of_order == 1
    assert bridge.read_state().position[0] == 0.001


# ---------------------------------------------------------------------------------------------
# bad packets: dropped, counted, harmless
# ---------------------------------------------------------------------------------------------
def test_bad_packets_are_dropped_and_counted(bridge, client, clock):
    deliver(bridge, client, pose(10, 1.0, 0.02))
    good = bridge.read_state().copy()
    body = bytearray(pose(11, 1.1, 0.5))

    def tagged(b):
        return bytes(b[:124]) + hmac.new(KEY, bytes(b[:124]), hashlib.sha256).digest()

    bad = {
        "oversized": [bytes(body) + b"\x00", bytes(5000), release(11, 1.1) + b"\x00",
                      encode_hello(KEY, 11, 1.1) + b"\x00"],
        "truncated": [bytes(body[:-1]), b"", b"ARSH", bytes(body[:72])],
        "bad_magic": [tagged(b"XRSH" + body[4:])],
        "bad_version": [tagged(body[:4] + b"\x02" + body[5:]), tagged(body[:4] + b"\x04" + body[5:]),
                        v1_pose(11, 1.1, 0.5)],
        "bad_type": [tagged(body[:5] + b"\x02" + body[6:]), encode_force(KEY, 11, 10, 1.1, 1.1, (0, 0, 1), session=SID),
                     encode_challenge(KEY, 11, 10, SID)],
        "bad_session": [pose(11, 1.1, 0.5, session=bytes(16)), pose(11, 1.1, 0.5, session=SID[::-1]),
                        release(11, 1.1, session=bytes(range(16)))],
        "bad_mac": [bytes(body[:50]) + b"\xff" + bytes(body[51:]), pose(11, 1.1, 0.5, key=OTHER_KEY),
                    bytes(body[:-1]) + bytes([body[-1] ^ 1]), bytes(body[:124]) + bytes(32),
                    release(11, 1.1, key=OTHER_KEY), encode_hello(OTHER_KEY, 11, 1.1)],
        "nonfinite": [pose(12, 1.2, math.nan), pose(12, math.inf, 0.1),
                      encode_pose(KEY, 12, 1.2, (0, 0, 0), quaternion=(math.nan, 0, 0, 0), session=SID)],
        "replayed": [pose(10, 1.0, 0.02), pose(10, 1.3, 0.5)],  # the accepted packet again; its number again
        "out_of_order": [pose(9, 1.3, 0.5)],  # older, never accepted
        "stale": [pose(13, 0.9, 0.5)],  # newer sequence, older client time
    }
    rng = np.random.default_rng(7)
    for _ in range(20):  # random junk of the right size is caught by magic, version or tag
        bad.setdefault("junk", []).append(rng.integers(0, 256, POSE_SIZE, dtype=np.uint8).tobytes())
    bad["junk"].append(b"ARSH\x03\x01" + rng.integers(0, 256, 10, dtype=np.uint8).tobytes() + SID
                       + rng.integers(0, 256, POSE_SIZE - 32, dtype=np.uint8).tobytes())
    for reason, packets in bad.items():
        for p in packets:
            deliver(bridge, client, p)
    st_ = bridge.stats
    for reason in ("oversized", "truncated", "bad_version", "bad_type", "bad_session", "nonfinite", "replayed",
                   "out_of_order", "stale"):
        assert getattr(st_, reason) == len(bad[reason]), reason
    assert st_.bad_mac == len(bad["bad_mac"]) + 1  # + the junk with a good header
    assert st_.bad_magic == len(bad["bad_magic"]) + 20  # + the random junk
    assert st_.accepted == 1 and st_.dropped == st_.received - 1 and st_.releases == 0
    s = bridge.read_state()
    np.testing.assert_array_equal(s.position, good.position)
    assert s.timestamp == good.timestamp and bridge.peer == client.getsockname()
    # and the next good packet is accepted
    clock.t += 0.001
    deliver(bridge, client, pose(14, 1.4, 0.03))
    assert bridge.read_state().position[0] == 0.03 and st_.accepted == 2


@settings(max_examples=300, deadline=None)
@given(data=st.binary(max_size=300), header=st.sampled_from([b"", b"ARSH\x03\x01", b"ARSH\x03\x03", b"ARSH\x03\x04",
                                                            b"ARSH\x02\x01", b"ARSH\x01\x01"]),
       pad_to_pose=st.booleans())
def test_no_datagram_without_the_key_is_accepted_or_raises(data, header, pad_to_pose):
    """Whatever the bytes (right header, right length or not), the bridge drops them, counts one
    reason, and the reference client's check does the same with FORCE-sized datagrams."""
    pkt = header + data
    if pad_to_pose:
        pkt = (pkt + bytes(POSE_SIZE))[:POSE_SIZE]
    dev = UdpBridgeDevice(LOOPBACK, 0, key=KEY)  # not opened: the parser alone, as poll() calls it
    dev._buf[:len(pkt)] = pkt
    assert dev._accept(len(pkt), ("127.0.0.1", 5)) is False
    assert dev.stats.dropped == 1 and dev.peer is None and dev._position.tolist() == [0.0, 0.0, 0.0]
    c = client_mod.HapticClient(LOOPBACK, 9, KEY)
    try:
        c.seq += 1
        fpkt = (b"ARSH\x03\x02" + data + bytes(FORCE_SIZE))[:FORCE_SIZE] if pad_to_pose else pkt
        assert c._check(fpkt, c.server) is None and c.invalid == 1
    finally:
        c.sock.close()


def test_forged_packets_neither_pin_nor_move(bridge, client, intruder, clock):
    """Without the key nobody becomes the peer, and nothing is sent back to anyone."""
    for k in range(5):
        deliver(bridge, intruder, pose(100 + k, float(k), 0.9, key=OTHER_KEY))
    assert bridge.peer is None and bridge.stats.bad_mac == 5 and bridge.stats.accepted == 0
    s = bridge.read_state()
    assert s.position.tolist() == [0.0, 0.0, 0.0] and s.timestamp == -math.inf
    bridge.command_force([0.0, 0.0, 1.0])
    assert bridge.stats.sent == 0 and nothing_pending(intruder)
    deliver(bridge, client, pose(1, 0.0, 0.01))  # the operator, with the key, is pinned
    assert bridge.peer == client.getsockname()


def test_a_hijack_after_the_operator_goes_silent_is_dropped(bridge, client, intruder, clock):
    """The operator is pinned for the session: once silent (> stale_after) the force it is sent
    fades to zero, and another sender, even one with the key, neither moves the probe nor hears
    anything."""
    deliver(bridge, client, pose(1, 0.0, 0.01))
    bridge.command_force([0.0, 0.0, 2.0])
    assert decode_force(KEY, client.recv(256))["force"][2] == 2.0
    filtered(bridge, intruder, pose(2, 0.001, 0.99), client)  # while the operator is fresh
    for k in range(20):  # the operator went silent: 10 ms steps, stale after 45 ms
        clock.t += 0.01
        filtered(bridge, intruder, pose(1000 + k, 5.0 + k, 0.99), client)  # with the key and newer numbers
        filtered(bridge, intruder, pose(2000 + k, 5.0 + k, 0.98, key=OTHER_KEY), client)  # without the key
        filtered(bridge, intruder, encode_hello(KEY, 3000 + k, 5.0 + k), client)  # asking for the session
        s = bridge.read_state()
        assert s.position[0] == 0.01 and s.timestamp == 100.0
        bridge.command_force([0.0, 0.0, 2.0])
        reply = decode_force(KEY, client.recv(256))  # still to the operator, fading
    assert reply["force"][2] == 0.0 and reply["flags"] & 1 and bridge.force_gain == 0.0
    assert bridge.peer == client.getsockname() and bridge.stats.accepted == 1
    assert bridge.stats.foreign == 0 and bridge.stats.dropped == 0 and bridge.stats.pins == 1  # never even queued
    assert nothing_pending(intruder)
    # the operator comes back: accepted (a resync), the force ramps back up
    clock.t += 0.01
    deliver(bridge, client, pose(5, 10.0, 0.02))
    assert bridge.read_state().position[0] == 0.02 and bridge.stats.resyncs == 1


def test_replayed_and_reordered_poses_are_dropped(bridge, client, clock):
    sent = {}
    for seq in (10, 11, 12, 14, 15):  # 13 is lost (or delayed)
        clock.t += 0.001
        sent[seq] = pose(seq, seq * 0.001, seq * 1e-3)
        deliver(bridge, client, sent[seq])
    assert bridge.stats.accepted == 5 and bridge.read_state().position[0] == 0.015
    for seq in (10, 12, 15, 14):  # recorded packets sent again
        clock.t += 0.001
        deliver(bridge, client, sent[seq])
    clock.t += 0.001
    deliver(bridge, client, pose(13, 0.0131, 0.5))  # the delayed one arrives late
    st_ = bridge.stats
    assert st_.replayed == 4 and st_.out_of_order == 1 and st_.accepted == 5
    assert bridge.read_state().position[0] == 0.015


def test_release_unpins_and_a_peer_timeout_is_opt_in(clock, client, intruder):
    with UdpBridgeDevice(LOOPBACK, 0, key=KEY, clock=clock, stale_after=0.045) as dev:
        dev.session = SID
        port = dev.address[1]
        deliver(dev, client, pose(1, 0.0, 0.01))
        clock.t += 3600.0  # an hour of silence: still pinned (no peer_timeout)
        filtered(dev, intruder, pose(2, 0.0, 0.5), client)
        assert dev.peer == client.getsockname()
        rel = release(3, 1.0)
        deliver(dev, client, rel)
        assert dev.address[1] == port  # unpinned: the socket is disconnected, on the same port
        assert dev.peer is None and dev.stats.releases == 1 and dev.force_gain == 0.0
        sent = dev.stats.sent
        dev.command_force([0.0, 0.0, 1.0])
        assert dev.stats.sent == sent  # nothing to the released client
        deliver(dev, intruder, rel)  # a replayed release, and a replayed pose
        deliver(dev, intruder, pose(1, 0.0, 0.01))
        assert dev.stats.replayed == 2 and dev.peer is None
        deliver(dev, intruder, pose(4, 0.0, 0.5))  # a new client with the key: pinned
        assert dev.peer == intruder.getsockname() and dev.read_state().position[0] == 0.5
    with UdpBridgeDevice(LOOPBACK, 0, key=KEY, clock=clock, stale_after=0.045, peer_timeout=0.5) as dev:
        dev.session = SID
        deliver(dev, client, pose(1, 0.0, 0.01))
        clock.t += 0.4
        filtered(dev, intruder, pose(2, 0.0, 0.5), client)
        clock.t += 0.2
        dev.poll()  # silent for 0.6 s > peer_timeout: unpinned, the socket takes anyone again
        assert dev.stats.peer_timeouts == 1 and dev.peer is None
        deliver(dev, intruder, pose(3, 0.0, 0.5))
        assert dev.peer == intruder.getsockname()
    with pytest.raises(HapticsError, match="peer_timeout must be a positive number"):
        UdpBridgeDevice(LOOPBACK, 0, peer_timeout=0.0)


class _Tap:
    """A client socket that keeps a copy of every datagram it sends (an eavesdropper on the wire)."""

    def __init__(self, sock):
        self._sock, self.sent = sock, []

    def sendto(self, data, addr):
        self.sent.append(bytes(data))
        return self._sock.sendto(data, addr)

    def __getattr__(self, name):
        return getattr(self._sock, name)


def _serve_client(dev, c, ticks):
    for k in range(ticks):
        c.send_pose((0.01 * math.cos(k / 10), 0.0, 0.0))
        deadline = time.monotonic() + 1.0
        while dev.poll() == 0 and dev.stats.hellos == 0 and time.monotonic() < deadline:
            pass
        dev.read_state()
        dev.command_force([0.0, 0.0, 0.5])
        c.poll()


def test_a_packet_recorded_in_an_earlier_session_cannot_pin(intruder):
    """The same key for two sessions (a key file that exists is reused): every datagram the
    operator's reference client sent in the first session, captured on the wire, is replayed at
    the start of the second from another socket. None pins, none moves the probe, nobody hears a
    force; the operator's client then starts the new session and is pinned."""
    with UdpBridgeDevice(LOOPBACK, 0, key=KEY) as dev:
        port = dev.address[1]
        c = client_mod.HapticClient(LOOPBACK, port, KEY)
        c.sock = tap = _Tap(c.sock)
        _serve_client(dev, c, 30)
        assert dev.stats.accepted >= 20 and c.stats["accepted"] >= 20  # a real session
        c.close()
        assert dev.poll() == 0 and dev.peer is None
    recorded = tap.sent
    assert len(recorded) >= 30
    with UdpBridgeDevice(LOOPBACK, port, key=KEY) as dev:  # the next session, same key, same port
        for data in recorded:
            deliver(dev, intruder, data)
        s = dev.read_state()
        assert dev.peer is None and dev.stats.accepted == 0 and dev.stats.pins == 0
        assert s.position.tolist() == [0.0, 0.0, 0.0] and s.timestamp == -math.inf
        assert dev.stats.bad_session == len(recorded) - dev.stats.hellos  # every POSE and the RELEASE
        intruder.settimeout(0.05)
        heard = []
        with pytest.raises(socket.timeout):
            while True:
                heard.append(intruder.recv(256))
        assert all(h[5] == 5 for h in heard)  # at most CHALLENGEs (the session id, no secret): never a FORCE
        c2 = client_mod.HapticClient(LOOPBACK, port, KEY)
        _serve_client(dev, c2, 10)
        assert dev.peer == c2.sock.getsockname() and dev.stats.pins == 1 and c2.stats["accepted"] > 0
        c2.close()


def test_stale_input_ramps_the_force_to_zero_and_back(bridge, client, clock):
    deliver(bridge, client, pose(1, 0.0))
    sent = []

    def tick(dt=0.01):
        clock.t += dt
        bridge.read_state()
        bridge.command_force([0.0, 0.0, 2.0])
        reply = decode_force(KEY, client.recv(256))
        sent.append((reply["force"][2], reply["flags"]))

    for _ in range(5):  # fresh for 0.04 s (stale_after 0.045 s)
        clock.t += 0.008
        deliver(bridge, client, pose(len(sent) + 2, clock.t - 100.0))
        bridge.command_force([0.0, 0.0, 2.0])
        reply = decode_force(KEY, client.recv(256))
        sent.append((reply["force"][2], reply["flags"]))
    for _ in range(10):  # silence: stale after 0.045 s, zero 0.05 s later
        tick()
    forces = np.array([f for f, _ in sent])
    np.testing.assert_allclose(forces[:5], 2.0)
    # the input goes stale on the 5th tick of silence (0.05 s > 0.045 s), then -0.4 N per 10 ms
    np.testing.assert_allclose(forces[5:15], [2.0, 2.0, 2.0, 2.0, 1.6, 1.2, 0.8, 0.4, 0.0, 0.0], atol=1e-9)
    assert sent[8][1] == 0 and sent[9][1] == 1 | 2 and sent[14][1] == 1
    # fresh again: back up in ramp_up = 0.1 s
    sent.clear()
    for k in range(12):
        clock.t += 0.01
        deliver(bridge, client, pose(100 + k, 10.0 + k * 0.01))
        bridge.command_force([0.0, 0.0, 2.0])
        sent.append(decode_force(KEY, client.recv(256))["force"][2])
    np.testing.assert_allclose(sent[:3], [0.2, 0.4, 0.6], atol=1e-9)
    assert sent[-1] == pytest.approx(2.0)
    assert bridge.stats.resyncs == 1


def test_reading_before_any_client_gives_a_stale_sample(clock):
    with UdpBridgeDevice(LOOPBACK, 0, clock=clock) as dev:
        assert len(dev.key) == 32  # generated: loopback needs no key from the operator
        s = dev.read_state()
        assert s.timestamp == -math.inf and math.isinf(dev.input_age()) and dev.stale
        dev.command_force([1.0, 0, 0])  # no peer: nothing sent, nothing raised
        assert dev.stats.sent == 0
        with pytest.raises(HapticsError, match="no valid pose packet on UDP 127.0.0.1"):
            dev.wait_for_client(timeout=0.01)


def test_bad_settings_and_busy_port():
    with pytest.raises(HapticsError, match="port must be an integer"):
        UdpBridgeDevice(LOOPBACK, 70000)
    with pytest.raises(HapticsError, match="stale_after must be a positive number"):
        UdpBridgeDevice(LOOPBACK, 0, stale_after=0.0)
    with pytest.raises(HapticsError, match="info must be a DeviceInfo"):
        UdpBridgeDevice(LOOPBACK, 0, info="touch")
    with pytest.raises(HapticsError, match="key must be 16 to 64 bytes"):
        UdpBridgeDevice(LOOPBACK, 0, key=b"short")
    with pytest.raises(HapticsError, match="key must be bytes"):
        UdpBridgeDevice(LOOPBACK, 0, key="00" * 32)
    with UdpBridgeDevice(LOOPBACK, 0) as a:
        b = UdpBridgeDevice(LOOPBACK, a.address[1])
        with pytest.raises(HapticsError, match="cannot listen on UDP"):
            b.open()


def test_non_loopback_binding_needs_a_key():
    for host in ("0.0.0.0", "192.168.1.5", "haptic-pc.lab"):
        assert not is_loopback(host)
        with pytest.raises(HapticsError, match="not loopback.*needs a key"):
            UdpBridgeDevice(host, 0)
        assert UdpBridgeDevice(host, 0, key=KEY).key == KEY  # with one it may (not opened here)
    assert is_loopback("127.0.0.1") and is_loopback("localhost") and is_loopback("127.1.2.3")


# ---------------------------------------------------------------------------------------------
# keys
# ---------------------------------------------------------------------------------------------
def test_keys_are_written_owner_only_and_refused_when_shared(tmp_path):
    key = generate_key()
    assert len(key) == 32 and key != generate_key()
    path = save_key(tmp_path / "k", key)
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o600
    assert load_key(path) == key and key_from_hex(Path(path).read_text()) == key
    with pytest.raises(HapticsError, match="already exists; refusing to overwrite"):
        save_key(path, generate_key())
    assert load_key(path) == key
    os.chmod(path, 0o644)
    with pytest.raises(HapticsError, match="accessible to other users.*chmod 600"):
        load_key(path)
    with pytest.raises(SystemExit, match="chmod 600"):
        client_mod.read_key(key_file=path)
    os.chmod(path, 0o600)
    assert client_mod.read_key(key_file=path) == key
    secret = "zz" + key.hex()[2:]
    with pytest.raises(HapticsError, match="hexadecimal digits only") as info:
        key_from_hex(secret)
    assert key.hex()[2:10] not in str(info.value)  # an error never repeats the key
    with pytest.raises(HapticsError, match="16 to 64 bytes"):
        key_from_hex("ab" * 8)
    with pytest.raises(HapticsError, match="cannot read the bridge key file"):
        load_key(tmp_path / "missing")


@pytest.mark.skipif(os.name != "posix" or os.geteuid() != 0, reason="planting a file as another user needs root")
def test_key_files_someone_else_could_have_planted_are_refused(tmp_path):
    """As ssh does for a private key: owner, mode and folder are checked, on the server and the
    reference client, on the opened file (a link, a FIFO or a directory is refused in one line)."""
    for path, needle in _planted_key_files(tmp_path):
        t0 = time.monotonic()
        with pytest.raises(HapticsError, match=needle) as info:
            load_key(path)
        assert len(str(info.value).splitlines()) == 1
        with pytest.raises(SystemExit) as info:
            client_mod.read_key(key_file=str(path))
        msg = str(info.value)
        assert len(msg.splitlines()) == 1 and (needle in msg or "cannot read" in msg), (path, msg)
        assert time.monotonic() - t0 < 1.0  # nothing blocks
    with pytest.raises(HapticsError, match="folder .* is writable by other users"):
        save_key(tmp_path / "shared" / "new.key", KEY)
    assert not (tmp_path / "shared" / "new.key").exists()


@pytest.mark.skipif(os.name != "posix" or os.geteuid() != 0, reason="running the client as another user needs root")
def test_the_reference_client_says_one_line_for_an_unreadable_key_file(tmp_path):
    """Run as an unprivileged user, the client cannot open its own mode-000 key file: one line
    on stderr naming the file, exit status non-zero, no traceback."""
    import subprocess
    import sys
    import tempfile

    d = tempfile.mkdtemp(prefix="arsurf-keytest-")
    try:
        os.chown(d, 65534, -1)
        os.chmod(d, 0o700)
        k = os.path.join(d, "bridge.key")
        Path(k).write_text(KEY.hex() + "\n")
        os.chown(k, 65534, -1)
        os.chmod(k, 0o000)
        client_py = os.path.join(d, "client.py")  # the one-file copy a haptic PC runs
        Path(client_py).write_bytes((ROOT / "arsurf" / "haptics" / "client.py").read_bytes())
        os.chmod(client_py, 0o644)
        python = None
        for cand in (sys.executable, os.path.realpath(sys.executable), "/usr/bin/python3"):
            try:
                if subprocess.run([cand, "-c", "0"], user=65534, group=65534, capture_output=True,
                                  timeout=30).returncode == 0:
                    python = cand
                    break
            except OSError:
                continue
        if python is None:
            pytest.skip("no Python interpreter the unprivileged user may run")
        r = subprocess.run([python, client_py, "--key-file", k, "--duration", "0"], capture_output=True,
                           text=True, user=65534, group=65534, timeout=30, cwd=d)
        err = r.stderr.strip()
        assert r.returncode != 0 and "Traceback" not in err and len(err.splitlines()) == 1, err
        assert k in err and "cannot read" in err
    finally:
        import shutil

        shutil.rmtree(d)


# ---------------------------------------------------------------------------------------------
# the client: no bad FORCE packet reaches the hand
# ---------------------------------------------------------------------------------------------
@pytest.fixture
def fake_server():
    """A socket standing in for the bridge, and a client with a hand-driven clock pointed at it."""
    srv = _udp()
    clk = FakeClock()
    c = client_mod.HapticClient(LOOPBACK, srv.getsockname()[1], KEY, max_force=7.9, timeout=0.1, clock=clk)
    assert c.send_pose((0.0, 0.0, 0.0)) is None and c.session is None  # no session yet: a HELLO instead
    hello = srv.recv(256)
    assert len(hello) == HELLO_SIZE and hello[5] == 4
    to_client(c, srv, encode_challenge(KEY, 0, struct.unpack_from("<Q", hello, 8)[0], SID))
    assert c.session == SID and c.stats["challenges"] == 1
    assert c.send_pose((0.0, 0.0, 0.0)) == c.seq  # now a POSE of that session
    assert decode_pose(KEY, srv.recv(256))["session"] == SID
    yield srv, c, clk
    c.close()
    srv.close()


def to_client(c, sock, data):
    before = c.stats["received"]
    sock.sendto(data, c.sock.getsockname())
    deadline = time.monotonic() + 1.0
    while c.stats["received"] == before:
        force = c.poll()
        if time.monotonic() > deadline:
            raise AssertionError("the datagram never reached the client")
        time.sleep(1e-4)
    return force


def test_the_client_applies_only_valid_forces(fake_server, intruder):
    srv, c, _ = fake_server
    ack = c.seq

    def force(seq, f, key=KEY, ack=ack, t=1.0, session=SID):
        return encode_force(key, seq, ack, t, 0.0, f, session=session)

    good = force(10, (0.0, 0.0, 1.0))
    assert to_client(c, srv, good) == (0.0, 0.0, 1.0)
    fb = bytearray(force(11, (0.0, 0.0, 2.0)))
    body = bytearray(fb[:80])
    v1 = struct.pack("<4sBBHIIdd3d", b"ARSH", 1, 2, 0, 11, ack & 0xFFFFFFFF, 1.0, 0.0, 0.0, 0.0, 5.0)
    attacks = {
        "nonfinite": [force(11, (math.nan, 0.0, 0.0)), force(12, (0.0, math.inf, 0.0)),
                      force(13, (0.0, 0.0, 1.0), t=math.nan)],
        "over_limit": [force(14, (0.0, 0.0, 1e6)), force(15, (0.0, 0.0, 8.0)), force(16, (6.0, 6.0, 0.0)),
                       force(17, (1e308, 1e308, 0.0))],
        "bad_mac": [force(18, (0.0, 0.0, 5.0), key=OTHER_KEY), bytes(fb[:40]) + b"\x40" + bytes(fb[41:]),
                    bytes(fb[:80]) + bytes(32), encode_challenge(OTHER_KEY, 18, ack, SID[::-1])],
        "replayed": [good, force(10, (0.0, 0.0, 3.0))],
        "out_of_order": [force(9, (0.0, 0.0, 3.0))],
        "bad_ack": [force(19, (0.0, 0.0, 3.0), ack=c.first_seq - 1), force(20, (0.0, 0.0, 3.0), ack=c.seq + 1),
                    encode_challenge(KEY, 21, c.first_seq - 1, SID[::-1])],  # a CHALLENGE of an earlier run
        "bad_session": [force(22, (0.0, 0.0, 3.0), session=bytes(16)), force(23, (0.0, 0.0, 3.0), session=SID[::-1])],
        "bad_version": [v1 + struct.pack("<I", zlib.crc32(v1))],
        "bad_type": [encode_pose(KEY, 24, 1.0, (0.0, 0.0, 0.0), session=SID)[:112], encode_hello(KEY, 25, 1.0)],
        "bad_magic": [b"XRSH" + bytes(fb[4:])],
        "truncated": [bytes(fb[:-1]), b"", b"ARSH"],
        "oversized": [bytes(fb) + b"\0", bytes(4000)],
    }
    del body
    for packets in attacks.values():
        for p in packets:
            assert to_client(c, srv, p) == (0.0, 0.0, 1.0)  # the hand still feels the good force only
    # a sender other than the server, even with the key and a fresh sequence number
    assert to_client(c, intruder, force(100, (0.0, 0.0, 4.0))) == (0.0, 0.0, 1.0)
    for reason, packets in attacks.items():
        assert c.stats[reason] == len(packets), reason
    assert c.stats["foreign"] == 1 and c.stats["accepted"] == 1 and c.session == SID
    assert c.invalid == c.stats["received"] - 2  # the good FORCE and the CHALLENGE
    # the next valid FORCE is applied; one right at the limit too
    assert to_client(c, srv, force(101, (0.0, 0.0, -7.9))) == (0.0, 0.0, -7.9)


def test_the_client_applies_zero_when_the_server_disappears(fake_server):
    srv, c, clk = fake_server
    assert to_client(c, srv, encode_force(KEY, 1, c.seq, 0.0, 0.0, (0.0, 0.0, 1.0), session=SID)) == (0.0, 0.0, 1.0)
    clk.t += 0.09
    assert c.poll() == (0.0, 0.0, 1.0)
    clk.t += 0.02  # 0.11 s without a valid FORCE (timeout 0.1 s)
    assert c.poll() == (0.0, 0.0, 0.0)
    # bad packets do not keep the old force alive
    to_client(c, srv, encode_force(OTHER_KEY, 2, c.seq, 0.0, 0.0, (0.0, 0.0, 1.0), session=SID))
    to_client(c, srv, encode_force(KEY, 1, c.seq, 0.0, 0.0, (0.0, 0.0, 1.0), session=SID))
    assert c.poll() == (0.0, 0.0, 0.0) and c.stats["accepted"] == 1


def test_a_fresh_client_ignores_forces_of_an_earlier_run(fake_server):
    """Recorded FORCE packets acknowledge poses of an earlier run: a restarted client (new
    sequence numbers, from the wall clock) drops them even though tag and sender are right."""
    srv, c, _ = fake_server
    old = [encode_force(KEY, 5 + k, c.first_seq - 1000 + k, 0.0, 0.0, (0.0, 0.0, 3.0), session=SID) for k in range(3)]
    for p in old:
        assert to_client(c, srv, p) == (0.0, 0.0, 0.0)
    assert c.stats["bad_ack"] == 3 and c.stats["accepted"] == 0


# ---------------------------------------------------------------------------------------------
# the CLI
# ---------------------------------------------------------------------------------------------
def test_the_cli_refuses_a_network_bridge_without_a_key(capsys, tmp_path):
    from arsurf.cli import main

    for argv, needle in ((["view", "--bridge-port", "0", "--host", "0.0.0.0"], "not loopback"),
                         (["view", "--host", "127.0.0.1"], "give --bridge-port"),
                         (["view", "--bridge-port", "0", "--bridge-key", "ab" * 32, "--bridge-key-file", "k"],
                          "not both"),
                         (["view", "--bridge-port", "0", "--bridge-key", "xyz"], "hexadecimal")):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "Traceback" not in err and needle in err, err
        assert "arsurf view: error:" in err


def test_the_cli_refuses_a_bad_recording_setup_before_anything_runs(capsys, tmp_path):
    from arsurf.cli import main

    existing = tmp_path / "old.h5"
    existing.write_bytes(b"an earlier recording")
    for argv, needle in ((["view", "--record", str(tmp_path / "r.h5")], "give --bridge-port"),
                         (["view", "--bridge-port", "0", "--record", str(existing)], "never replaces"),
                         (["view", "--bridge-port", "0", "--record", str(tmp_path / "no" / "r.h5")], "folder"),
                         (["view", "--frames", "0"], "--frames 0"),
                         (["view", "--realtime-priority", "5"], "give --bridge-port"),
                         (["view", "--no-realtime-priority"], "--no-realtime-priority set up the UDP bridge"),
                         (["view", "--bridge-port", "0", "--tubes"], "--tubes")):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "Traceback" not in err and needle in err, err
    assert existing.read_bytes() == b"an earlier recording" and list(tmp_path.iterdir()) == [existing]


def test_the_cli_makes_an_owner_only_key_file(tmp_path, capsys):
    from arsurf.cli import build_parser
    from arsurf.cli.view import _bridge_setup

    args = build_parser().parse_args(["view", "--bridge-port", "0"])
    b = _bridge_setup(args)
    try:
        assert b.host == LOOPBACK and load_key(b.key_file) == b.key
        assert stat.S_IMODE(os.stat(b.key_file).st_mode) == 0o600
        assert stat.S_IMODE(os.stat(b.tmpdir).st_mode) == 0o700
        err = capsys.readouterr().err
        assert b.key_file in err and b.key.hex() not in err  # the path is printed, never the key
    finally:
        import shutil

        shutil.rmtree(b.tmpdir)
    path = tmp_path / "session.key"
    args = build_parser().parse_args(["view", "--bridge-port", "0", "--host", "0.0.0.0", "--bridge-key-file",
                                      str(path), "--bridge-peer-timeout", "2"])
    b = _bridge_setup(args)
    assert b.host == "0.0.0.0" and load_key(path) == b.key and b.tmpdir is None and b.peer_timeout == 2.0
    assert _bridge_setup(args).key == b.key  # an existing file is read, not replaced


# ---------------------------------------------------------------------------------------------
# the reference client end to end
# ---------------------------------------------------------------------------------------------
def test_reference_client_against_the_bridge(capsys, tmp_path):
    """The client script runs its circle for 0.3 s; the bridge serves it with a bounded loop."""
    info = DeviceInfo("remote", 5.0, (0.2, 0.2, 0.2), (1e3, 1e3, 1e3))
    with UdpBridgeDevice(LOOPBACK, 0, info=info) as dev:
        key_file = save_key(tmp_path / "bridge.key", dev.key)
        port = dev.address[1]
        th = threading.Thread(target=client_mod.main, args=(["--port", str(port), "--key-file", key_file, "--rate",
                                                              "500", "--duration", "0.3", "--radius", "0.01",
                                                              "--max-force", "5.0"],))
        th.start()
        radii = []
        deadline = time.monotonic() + 5.0
        while (th.is_alive() or dev.peer is not None) and time.monotonic() < deadline:
            s = dev.read_state()
            if math.isfinite(s.timestamp):
                radii.append(math.hypot(s.position[0], s.position[1]))
                dev.command_force(-100.0 * s.position)  # a spring to the centre
            time.sleep(0.001)
        th.join(5.0)
    assert not th.is_alive()
    summary = json.loads(capsys.readouterr().out)
    assert summary["sent"] == 150 and summary["invalid_replies"] == 0
    assert summary["replies_with_rtt"] > 0 and summary["max_force_N"] == pytest.approx(1.0, rel=0.05)
    assert dev.stats.accepted > 0 and dev.stats.dropped == 0
    assert dev.stats.releases == 1 and dev.peer is None  # the client said goodbye on exit
    np.testing.assert_allclose(radii, 0.01, rtol=1e-9)


def test_the_python_client_converts_the_openhaptics_frame_as_the_protocol_states():
    """docs/bridge.rst: HD (x right, y up, z towards the operator, mm) -> the bridge's frame (x right,
    y away, z up, m) is (x, -z, y) 1e-3; the force back is (Fx, Fz, -Fy). A press down is -z, the
    surface's push back up is HD +y, and the power F.v is the same in both frames (a rotation)."""
    from arsurf.haptics.client import from_openhaptics, to_openhaptics

    assert from_openhaptics((0.0, -2.0, 0.0)) == (0.0, 0.0, -2e-3)
    assert to_openhaptics((0.0, 0.0, 1.5)) == (0.0, 1.5, 0.0)
    assert from_openhaptics((0.0, 0.0, 3.0)) == (0.0, -3e-3, 0.0)  # towards the operator: -y in the bridge
    rng = np.random.default_rng(4)
    for v_hd, f in zip(rng.normal(size=(20, 3)), rng.normal(size=(20, 3))):
        v = np.array(from_openhaptics(v_hd))
        assert np.isclose(np.dot(to_openhaptics(f), v_hd) * 1e-3, np.dot(f, v), rtol=1e-12, atol=0)
        assert np.isclose(np.linalg.norm(v), 1e-3 * np.linalg.norm(v_hd), rtol=1e-12)
