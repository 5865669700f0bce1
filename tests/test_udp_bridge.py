"""UDP bridge on loopback: the protocol, good and bad packets, stale input, the reference client."""
from __future__ import annotations

import importlib.util
import json
import math
import socket
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
    FORCE_SIZE,
    POSE_SIZE,
    UdpBridgeDevice,
    decode_force,
    decode_pose,
    encode_force,
    encode_pose,
)

_spec = importlib.util.spec_from_file_location("haptic_client", Path(__file__).resolve().parents[1] / "tools" / "haptic_client.py")
client_mod = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(client_mod)

LOOPBACK = "127.0.0.1"


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
    dev = UdpBridgeDevice(LOOPBACK, 0, clock=clock, stale_after=0.045, ramp_down=0.05, ramp_up=0.1)
    dev.open()
    yield dev
    dev.close()


@pytest.fixture
def client():
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind((LOOPBACK, 0))
    s.settimeout(1.0)
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


def pose(seq, t, x=0.0, **kw):
    return encode_pose(seq=seq, t=t, position=(x, 0.0, 0.0), **kw)


# ---------------------------------------------------------------------------------------------
# the layout
# ---------------------------------------------------------------------------------------------
def test_packet_layout_matches_the_documented_offsets():
    pkt = encode_pose(seq=0x01020304, t=1.5, position=(1.0, 2.0, 3.0), velocity=(4.0, 5.0, 6.0),
                      quaternion=(0.5, 0.5, 0.5, 0.5), buttons=0xA5, reset=True)
    assert len(pkt) == POSE_SIZE == 108
    assert pkt[0:4] == b"ARSH" and pkt[4] == 1 and pkt[5] == 1
    assert struct.unpack_from("<H", pkt, 6)[0] == 1  # RESET
    assert struct.unpack_from("<I", pkt, 8)[0] == 0x01020304
    assert struct.unpack_from("<d", pkt, 12)[0] == 1.5
    assert struct.unpack_from("<3d", pkt, 20) == (1.0, 2.0, 3.0)
    assert struct.unpack_from("<3d", pkt, 44) == (4.0, 5.0, 6.0)
    assert struct.unpack_from("<4d", pkt, 68) == (0.5, 0.5, 0.5, 0.5)
    assert struct.unpack_from("<I", pkt, 100)[0] == 0xA5
    assert struct.unpack_from("<I", pkt, 104)[0] == zlib.crc32(pkt[:104])
    f = encode_force(seq=9, ack=8, t=2.0, echo=1.5, force=(0.1, 0.2, 0.3), flags=2)
    assert len(f) == FORCE_SIZE == 60
    assert f[0:4] == b"ARSH" and f[4] == 1 and f[5] == 2 and struct.unpack_from("<H", f, 6)[0] == 2
    assert struct.unpack_from("<IIdd3d", f, 8) == (9, 8, 2.0, 1.5, 0.1, 0.2, 0.3)
    assert struct.unpack_from("<I", f, 56)[0] == zlib.crc32(f[:56])


@settings(max_examples=100, deadline=None)
@given(seq=st.integers(0, 2**32 - 1), t=st.floats(allow_nan=False), buttons=st.integers(0, 2**32 - 1),
       pos=st.lists(st.floats(allow_nan=False), min_size=3, max_size=3),
       vel=st.lists(st.floats(), min_size=3, max_size=3), reset=st.booleans())
def test_reference_client_and_bridge_agree_byte_for_byte(seq, t, buttons, pos, vel, reset):
    a = encode_pose(seq, t, pos, vel, (1.0, 0.0, 0.0, 0.0), buttons, reset)
    b = client_mod.encode_pose(seq, t, pos, vel, (1.0, 0.0, 0.0, 0.0), buttons, reset)
    assert a == b
    d = decode_pose(a)
    assert d["seq"] == seq and d["buttons"] == buttons and d["flags"] == int(reset)
    f = encode_force(seq, seq ^ 1, t, t, pos, flags=3)
    assert client_mod.decode_force(f) == decode_force(f)


# ---------------------------------------------------------------------------------------------
# good packets
# ---------------------------------------------------------------------------------------------
def test_poses_in_forces_out_on_loopback(bridge, client, clock):
    deliver(bridge, client, pose(1, 0.0, 0.01, velocity=(0.1, 0.0, 0.0), buttons=1, quaternion=(2.0, 0, 0, 0)))
    s = bridge.read_state()
    np.testing.assert_array_equal(s.position, [0.01, 0.0, 0.0])
    np.testing.assert_array_equal(s.velocity, [0.1, 0.0, 0.0])
    assert s.buttons == 1 and s.timestamp == clock.t and bridge.input_age() == 0.0
    np.testing.assert_array_equal(bridge.orientation, [1.0, 0, 0, 0])  # normalised
    bridge.command_force([0.0, 0.5, 0.0])
    reply = decode_force(client.recv(256))
    assert reply["ack"] == 1 and reply["force"] == (0.0, 0.5, 0.0) and reply["echo"] == 0.0 and reply["flags"] == 0
    # without velocity the bridge differentiates positions with the client timestamps
    clock.t += 0.001
    deliver(bridge, client, pose(2, 0.002, 0.0102))
    s = bridge.read_state()
    np.testing.assert_allclose(s.velocity, [0.1, 0.0, 0.0], rtol=1e-9)
    # a force above the device limit is clamped and flagged in the reply
    bridge.command_force([0.0, 0.0, 100.0])
    reply = decode_force(client.recv(256))
    assert reply["force"][2] == pytest.approx(7.9) and reply["flags"] & 4


def test_sequence_numbers_wrap_around(bridge, client, clock):
    deliver(bridge, client, pose(2**32 - 1, 0.0, reset=True))
    clock.t += 0.001
    deliver(bridge, client, pose(0, 0.001, 0.001))
    assert bridge.stats.accepted == 2 and bridge.stats.out_of_order == 0
    assert bridge.read_state().position[0] == 0.001


# ---------------------------------------------------------------------------------------------
# bad packets: dropped, counted, harmless
# ---------------------------------------------------------------------------------------------
def test_bad_packets_are_dropped_and_counted(bridge, client, clock):
    deliver(bridge, client, pose(10, 1.0, 0.02))
    good = bridge.read_state().copy()
    body = bytearray(pose(11, 1.1, 0.5))
    wrong_magic = b"XRSH" + bytes(body[4:104])
    wrong_version = bytes(body[:4]) + b"\x02" + bytes(body[5:104])
    wrong_type = bytes(body[:5]) + b"\x02" + bytes(body[6:104])
    bad = {
        "oversized": [bytes(body) + b"\x00", bytes(5000)],
        "truncated": [bytes(body[:-1]), b"", b"ARSH"],
        "bad_magic": [wrong_magic + struct.pack("<I", zlib.crc32(wrong_magic))],
        "bad_version": [wrong_version + struct.pack("<I", zlib.crc32(wrong_version))],
        "bad_type": [wrong_type + struct.pack("<I", zlib.crc32(wrong_type))],
        "bad_crc": [bytes(body[:50]) + b"\xff" + bytes(body[51:])],
        "nonfinite": [pose(12, 1.2, math.nan), pose(12, math.inf, 0.1),
                      encode_pose(12, 1.2, (0, 0, 0), quaternion=(math.nan, 0, 0, 0))],
        "out_of_order": [pose(9, 1.3, 0.5), pose(10, 1.3, 0.5)],  # older, duplicate
        "stale": [pose(13, 0.9, 0.5)],  # newer sequence, older client time
    }
    rng = np.random.default_rng(7)
    for _ in range(20):  # random junk of the right size is caught by magic or CRC
        bad.setdefault("junk", []).append(rng.integers(0, 256, POSE_SIZE, dtype=np.uint8).tobytes())
    for reason, packets in bad.items():
        for p in packets:
            deliver(bridge, client, p)
    st_ = bridge.stats
    for reason in ("oversized", "truncated", "bad_magic", "bad_version", "bad_type", "bad_crc", "nonfinite",
                   "out_of_order", "stale"):
        assert getattr(st_, reason) >= len(bad[reason]), reason
    assert st_.accepted == 1 and st_.dropped == st_.received - 1
    s = bridge.read_state()
    np.testing.assert_array_equal(s.position, good.position)
    assert s.timestamp == good.timestamp
    # and the next good packet is accepted
    clock.t += 0.001
    deliver(bridge, client, pose(14, 1.4, 0.03))
    assert bridge.read_state().position[0] == 0.03 and st_.accepted == 2


def test_a_second_sender_is_foreign_until_the_first_goes_stale(bridge, client, clock):
    deliver(bridge, client, pose(1, 0.0, 0.01))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as intruder:
        intruder.bind((LOOPBACK, 0))
        deliver(bridge, intruder, pose(500, 5.0, 0.99, reset=True))
        assert bridge.stats.foreign == 1 and bridge.read_state().position[0] == 0.01
        clock.t += 0.2  # the first client went silent: a new one may take over, any sequence number
        deliver(bridge, intruder, pose(7, 0.0, 0.04))
        assert bridge.read_state().position[0] == 0.04 and bridge.peer == intruder.getsockname()
        assert bridge.stats.resyncs == 1


def test_stale_input_ramps_the_force_to_zero_and_back(bridge, client, clock):
    deliver(bridge, client, pose(1, 0.0))
    sent = []

    def tick(dt=0.01):
        clock.t += dt
        bridge.read_state()
        bridge.command_force([0.0, 0.0, 2.0])
        reply = decode_force(client.recv(256))
        sent.append((reply["force"][2], reply["flags"]))

    for _ in range(5):  # fresh for 0.04 s (stale_after 0.045 s)
        clock.t += 0.008
        deliver(bridge, client, pose(len(sent) + 2, clock.t - 100.0))
        bridge.command_force([0.0, 0.0, 2.0])
        reply = decode_force(client.recv(256))
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
        sent.append(decode_force(client.recv(256))["force"][2])
    np.testing.assert_allclose(sent[:3], [0.2, 0.4, 0.6], atol=1e-9)
    assert sent[-1] == pytest.approx(2.0)
    assert bridge.stats.resyncs == 1


def test_reading_before_any_client_gives_a_stale_sample(clock):
    with UdpBridgeDevice(LOOPBACK, 0, clock=clock) as dev:
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
    with UdpBridgeDevice(LOOPBACK, 0) as a:
        b = UdpBridgeDevice(LOOPBACK, a.address[1])
        with pytest.raises(HapticsError, match="cannot listen on UDP"):
            b.open()


def test_reference_client_against_the_bridge(capsys):
    """The client script runs its circle for 0.3 s; the bridge serves it with a bounded loop."""
    info = DeviceInfo("remote", 5.0, (0.2, 0.2, 0.2), (1e3, 1e3, 1e3))
    with UdpBridgeDevice(LOOPBACK, 0, info=info) as dev:
        port = dev.address[1]
        th = threading.Thread(target=client_mod.main, args=(["--port", str(port), "--rate", "500", "--duration", "0.3",
                                                              "--radius", "0.01"],))
        th.start()
        radii = []
        deadline = time.monotonic() + 5.0
        while th.is_alive() and time.monotonic() < deadline:
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
    np.testing.assert_allclose(radii, 0.01, rtol=1e-9)
