"""The Nanonis link: the protocol bytes (the vendor document's examples and the vendor package's own
encoder), the backend against the simulated controller (positions, signals, limits, error replies),
and a link that is slow, stalls, dies or talks nonsense."""
from __future__ import annotations

import math
import socket
import struct

import numpy as np
import pytest

from arsurf.errors import ControllerError, InstrumentError, InstrumentLinkLost
from arsurf.instrument import nanonis_protocol as proto
from arsurf.instrument.instrument import PhotodiodeNoise, VirtualAFM
from arsurf.instrument.interface import InstrumentLimits
from arsurf.instrument.nanonis import NanonisAFM, NanonisConnection
from arsurf.instrument.nanonis_sim import SIGNAL_NAMES, Faults, NanonisSimulator

pytestmark = pytest.mark.timeout(120)

X0, Y0 = 5e-6, 5e-6
LIMITS = InstrumentLimits((0.0, 0.0, -5e-6), (20e-6, 20e-6, 5e-6), 50e-6)
QUIET = PhotodiodeNoise(peak_to_peak=1e-4)


def _afm(**kw):
    kw = {"probe_height": 0.3e-6, "tip_xy": (X0, Y0), "noise": QUIET, "keep_history": False, **kw}
    return VirtualAFM(0.0, **kw)


@pytest.fixture()
def sim():
    with NanonisSimulator(_afm()) as s:
        yield s


@pytest.fixture()
def nanonis(sim):
    with NanonisAFM(*sim.address, limits=LIMITS, timeout=0.5) as n:
        yield n


# ---------------------------------------------------------------------------------------------
# the bytes of the protocol


def test_request_and_reply_bytes_are_the_protocol_documents_example():
    """TCP Protocol R14718, "Return the tip position": FolMe.XYPosGet with wait = True, and the
    reply X = 5 nm, Y = -5 nm, no error, byte for byte."""
    req = proto.encode_request("FolMe.XYPosGet", (1,))
    want = ("466F6C4D652E5859506F73476574" + "00" * 18 + "00000004" + "0001" + "0000" + "00000001")
    assert req.hex().upper() == want.upper()
    reply = proto.encode_reply("FolMe.XYPosGet", (5e-9, -5e-9))
    assert reply[32:36].hex() == "00000018" and reply[36:40] == bytes(4)  # body 24 bytes, 4 unused
    assert reply[40:].hex().upper() == "3E35798EE2308C3ABE35798EE2308C3A" + "0000000000000000"
    assert proto.parse_header(reply[:40]) == ("FolMe.XYPosGet", 24, 1)
    assert proto.decode_reply("FolMe.XYPosGet", reply[40:]) == (5e-9, -5e-9)
    # FolMe.XYPosSet: X = 10 nm, Y = 15 nm, wait; body 20 bytes (the document's second example)
    req = proto.encode_request("FolMe.XYPosSet", (10e-9, 15e-9, 1))
    assert req[32:40].hex() == "0000001400010000"
    assert req[40:].hex().upper() == "3E45798EE2308C3A" + "3E501B2B29A4692B" + "00000001"


def test_error_section_becomes_one_line_controller_error():
    body = proto.encode_reply_body("ZCtrl.ZPosSet", (), "Z-Controller is on\nsecond line")
    with pytest.raises(ControllerError, match=r"^the Nanonis controller refused ZCtrl.ZPosSet: Z-Controller is on$"):
        proto.decode_reply("ZCtrl.ZPosSet", body)
    # status 1 without a description is an error too, status 2 is not the protocol
    with pytest.raises(ControllerError, match="no description"):
        proto.decode_reply("FolMe.Stop", struct.pack(">Ii", 1, 0))
    with pytest.raises(InstrumentLinkLost, match="neither 0 nor 1"):
        proto.decode_reply("FolMe.Stop", struct.pack(">Ii", 2, 0))


def test_arrays_and_strings_round_trip():
    names = list(SIGNAL_NAMES)
    assert proto.decode_reply("Signals.NamesGet", proto.encode_reply_body("Signals.NamesGet", (names,))) == (names,)
    vals = [1.5, -2.25, 0.0]
    assert proto.decode_reply("Signals.ValsGet", proto.encode_reply_body("Signals.ValsGet", (vals,))) == (tuple(vals),)
    req = proto.encode_request("Signals.ValsGet", ([3, 20, 21], 0))
    assert proto.parse_header(req[:40], request=True) == ("Signals.ValsGet", 20, 1)
    assert proto.decode_request("Signals.ValsGet", req[40:]) == ((3, 20, 21), 0)


@pytest.mark.parametrize("body, match", [
    (struct.pack(">i", 5) + b"\0" * 8 + struct.pack(">Ii", 0, 0), "truncated"),       # 5 floats promised, 2 there
    (struct.pack(">i", -1) + struct.pack(">Ii", 0, 0), "negative"),                     # a negative count
    (struct.pack(">i", 1 << 30) + struct.pack(">Ii", 0, 0), "truncated"),              # a count no body holds
    (struct.pack(">i", 0) + struct.pack(">Ii", 0, 1 << 20), "a string of"),            # a huge error text
    (struct.pack(">i", 0) + struct.pack(">Ii", 0, 0) + b"x", "unexpected bytes"),      # trailing bytes
])
def test_malformed_replies_are_refused_before_anything_is_allocated(body, match):
    with pytest.raises(InstrumentLinkLost, match=match):
        proto.decode_reply("Signals.ValsGet", body)


def test_headers_that_are_not_the_protocol_are_refused():
    good = proto.encode_reply("ZCtrl.ZPosGet", (1e-9,))[:40]
    with pytest.raises(InstrumentLinkLost, match="outside"):
        proto.parse_header(good[:32] + struct.pack(">i", -4) + bytes(4))
    with pytest.raises(InstrumentLinkLost, match="outside"):
        proto.parse_header(good[:32] + struct.pack(">i", proto.MAX_BODY + 1) + bytes(4))
    with pytest.raises(InstrumentLinkLost, match="not ASCII"):
        proto.parse_header(b"\xff" * 32 + good[32:])
    with pytest.raises(InstrumentLinkLost, match="39 bytes"):
        proto.parse_header(good[:39])


def test_fuzzed_bytes_raise_only_the_link_errors(rng):
    """A seeded sample (the big run: bench/fuzz_nanonis.py): random and mutated bodies of every
    reply never raise anything but InstrumentLinkLost / ControllerError."""
    seeds = {c: proto.encode_reply_body(c, _reply_values(c)) for c in proto.COMMANDS}
    for i in range(3000):
        command = list(proto.COMMANDS)[i % len(proto.COMMANDS)]
        base = bytearray(seeds[command])
        if i % 3 == 0:
            data = rng.integers(0, 256, rng.integers(0, 64), dtype=np.uint8).tobytes()
        else:
            for _ in range(rng.integers(1, 4)):
                if base:
                    base[rng.integers(0, len(base))] = rng.integers(0, 256)
            data = bytes(base[:rng.integers(0, len(base) + 1)]) if i % 3 == 2 else bytes(base)
        try:
            proto.decode_reply(command, data)
        except (InstrumentLinkLost, ControllerError):
            pass
        try:
            proto.decode_request(command, data)
        except InstrumentLinkLost:
            pass
        try:
            proto.parse_header(data[:40].ljust(40, b"\0"), request=bool(i % 2))
        except InstrumentLinkLost:
            pass


_SAMPLE_VALUES = {"*+c": ["X (m)", "Input 1 (V)"], "*f": [1.0, 2.0, 3.0], "*i": [0, 3, 7], "*-c": "Z (m)",
                  "2f": np.arange(12.0).reshape(3, 4) * 1e-9}


def _reply_values(command: str) -> tuple:
    """One value per return value as the caller gives it (an array stands for its counts)."""
    return tuple(_SAMPLE_VALUES.get(c, 1 if c in "HIi" else 1.5e-9) for c in proto._logical(proto.COMMANDS[command][1]))


# ---------------------------------------------------------------------------------------------
# the vendor's package: the same bytes, and its client against the simulator

def _vendor():
    return pytest.importorskip("nanonis_spm", reason="the vendor package nanonis-spm is not installed "
                                                     "(pip install 'arsurf[nanonis]')")


class _Capture:
    """A connection object for nanonis_spm.Nanonis: records what it sends, answers ``reply``."""

    def __init__(self, reply: bytes) -> None:
        self.sent, self.reply = b"", reply

    def send(self, data):
        self.sent += bytes(data)
        return len(data)

    def recv(self, n):
        out, self.reply = self.reply[:n], self.reply[n:]
        return out

    def settimeout(self, t):
        pass


_VENDOR_ARGS = {
    "FolMe.XYPosGet": (1,), "FolMe.XYPosSet": (1.25e-6, -2.5e-6, 0), "FolMe.SpeedSet": (2e-6, 1),
    "ZCtrl.ZPosSet": (3e-9,), "ZCtrl.OnOffSet": (1,), "ZCtrl.Withdraw": (1, 5000), "Signals.ValsGet": ([3, 20, 21], 0),
    "AutoApproach.OnOffSet": (1,), "Util.AcqPeriodSet": (0.005,),
}


@pytest.mark.parametrize("command", sorted(c for c in proto.COMMANDS if not c.startswith("Scan.")))
def test_requests_and_replies_match_the_vendor_package_byte_for_byte(command):
    nanonis_spm = _vendor()
    args = _VENDOR_ARGS.get(command, ())
    values = _reply_values(command)
    conn = _Capture(proto.encode_reply(command, values))
    client = nanonis_spm.Nanonis(conn)
    vendor_args = [list(a) if isinstance(a, list) else a for a in args]
    error, _, parsed = getattr(client, command.replace(".", "_"))(*vendor_args)
    assert conn.sent == proto.encode_request(command, args)
    assert error == ""
    # the vendor keeps array counts and wraps each array element in a tuple; ours replaces the counts
    flat = [v for v in parsed if not isinstance(v, list)]
    arrays = [[e[0] if isinstance(e, tuple) else e for e in v] for v in parsed if isinstance(v, list)]
    ours = proto.decode_reply(command, proto.encode_reply_body(command, values))
    if arrays:
        assert [list(a) for a in ours] == arrays
    else:
        assert tuple(flat) == pytest.approx(ours, rel=1e-6)


def test_the_vendor_client_drives_the_simulator(sim):
    nanonis_spm = _vendor()
    s = socket.create_connection(sim.address, timeout=5.0)
    try:
        client = nanonis_spm.Nanonis(s)
        err, _, (x, y) = client.FolMe_XYPosGet(0)
        assert err == "" and (x, y) == pytest.approx((X0, Y0), abs=1e-15)
        client.FolMe_XYPosSet(np.float64(7e-6), np.float64(6e-6), np.uint32(1))
        assert sim.instrument.tip_xy.tolist() == pytest.approx([7e-6, 6e-6], abs=1e-12)
        err, _, names = client.Signals_NamesGet()
        assert names[2] == list(SIGNAL_NAMES)
        err, _, (high, low) = client.ZCtrl_LimitsGet()
        assert low < high
        client.ZCtrl_OnOffSet(np.uint32(1))
        err, _, _ = client.ZCtrl_ZPosSet(np.float32(1e-9))  # refused: the controller is on
        assert "Z-Controller is on" in err
    finally:
        s.close()


# ---------------------------------------------------------------------------------------------
# the backend against the simulated controller


def test_read_gives_the_instruments_position_and_signals(nanonis, sim):
    afm = sim.instrument
    assert nanonis.signal_names == ("X (m)", "Y (m)", "Z (m)", "Input 1 (V)", "Input 2 (V)")
    s = nanonis.read()
    assert s.position == pytest.approx([X0, Y0, afm.tip_z()], rel=1e-6)  # float32 on the wire
    assert np.all(np.abs(s.signals) < 1e-3)  # a free lever: offset 0 and noise
    # press the tip 20 nm into the surface (feedback off): the deflection signal is delta / S_n
    nanonis.move_to((math.nan, math.nan, -20e-9))
    s = nanonis.read()
    assert s.position[2] == pytest.approx(-20e-9, abs=1e-12)
    assert s.signals[0] == pytest.approx(20e-9 / afm.deflection_sensitivity, abs=1e-3)
    assert afm.history().time.size == 0  # the server's instrument keeps no history


def test_moves_reach_the_instrument_and_limits_are_enforced_before_sending(nanonis, sim):
    nanonis.move_to((8e-6, 3e-6, math.nan), wait=True)
    assert sim.instrument.tip_xy.tolist() == pytest.approx([8e-6, 3e-6], abs=1e-12)
    assert nanonis.read().position[:2] == pytest.approx([8e-6, 3e-6], rel=1e-6)
    sent = dict(sim.requests)
    with pytest.raises(InstrumentError, match=r"target x = 2.5e-05 m is outside the instrument's limits \[0, 2e-05\]"):
        nanonis.move_to((25e-6, 3e-6, math.nan))
    with pytest.raises(InstrumentError, match="not open|x and y are commanded together"):
        nanonis.move_to((1e-6, math.nan, math.nan))
    assert sim.requests == sent  # nothing reached the controller
    # the controller's Z limits narrow the user's box; the Follow Me speed is the user's
    assert nanonis.limits.high[2] == pytest.approx(sim.instrument.limits.high[2], rel=1e-6)
    assert nanonis.limits.low[2] > LIMITS.low[2] and sim.speed == pytest.approx(LIMITS.max_speed)


def test_z_needs_the_feedback_off_and_engage_withdraw(nanonis, sim):
    afm = sim.instrument
    nanonis.engage()
    assert nanonis.feedback and afm.feedback
    s = nanonis.read()
    assert s.signals[0] == pytest.approx(afm.setpoint, abs=2e-3)  # the feedback holds the set point
    with pytest.raises(InstrumentError, match="Z feedback is on, so Z cannot be commanded"):
        nanonis.move_to((X0, Y0, 0.0))
    nanonis.move_to((6e-6, Y0, math.nan))  # XY while the feedback holds Z
    assert nanonis.read().signals[0] == pytest.approx(afm.setpoint, abs=2e-3)
    nanonis.withdraw()
    assert not nanonis.feedback and not afm.feedback
    assert afm.position["pico"] == 0.0 and afm.gap() > 0.0 and abs(nanonis.read().signals[0]) < 2e-3


def test_error_replies_surface_as_one_line_and_the_link_stays_usable(nanonis, sim):
    sim.faults.errors["FolMe.XYPosSet"] = "Follow Me is busy\n(code 12)"
    with pytest.raises(ControllerError) as info:
        nanonis.move_to((6e-6, 6e-6, math.nan))
    assert str(info.value) == "the Nanonis controller refused FolMe.XYPosSet: Follow Me is busy"
    del sim.faults.errors["FolMe.XYPosSet"]
    nanonis.move_to((6e-6, 6e-6, math.nan))
    assert nanonis.read().position[0] == pytest.approx(6e-6, rel=1e-6)
    # the controller refuses Z with its Z controller on, even if the client thought it off
    nanonis.set_feedback(True)
    nanonis._feedback = False
    with pytest.raises(ControllerError, match="Z-Controller is on"):
        nanonis.move_to((6e-6, 6e-6, 0.0))


def test_unknown_signal_names_list_the_controllers(sim):
    afm = NanonisAFM(*sim.address, limits=LIMITS, deflection="Deflection (V)")
    with pytest.raises(InstrumentError, match=r"no signal 'Deflection \(V\)' for the deflection; its signals are "
                                              r"'Current \(A\)', 'Bias \(V\)'"):
        afm.open()
    assert not afm.is_open
    with NanonisAFM(*sim.address, limits=LIMITS, deflection="input 3 (v)", torsion=4) as n:
        assert n.signal_names[3:] == ("Input 3 (V)", "Input 3 (V)")


def test_a_box_wider_than_the_piezo_range_is_refused(sim):
    wide = InstrumentLimits((0.0, 0.0, -1e-6), (200e-6, 20e-6, 1e-6), 1e-6)
    with pytest.raises(InstrumentError, match="x limits span 0.0002 m, more than the controller's piezo range"):
        NanonisAFM(*sim.address, limits=wide).open()


def test_nothing_listens(sim):
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    with pytest.raises(InstrumentLinkLost, match=rf"cannot connect to Nanonis at 127.0.0.1:{port}"):
        NanonisAFM("127.0.0.1", port, limits=LIMITS, connect_timeout=0.5).open()


# ---------------------------------------------------------------------------------------------
# slow, stalled, dead and garbled links


def test_slow_replies_within_the_timeout_are_fine(nanonis, sim):
    sim.faults.delay = 0.02
    sim.faults.delay_every = 2
    for _ in range(6):
        s = nanonis.read()
    assert s.position[0] == pytest.approx(X0, rel=1e-6)


def test_a_stalled_link_raises_after_the_timeout_and_stays_closed(nanonis, sim):
    sim.faults.stall_after = 0  # the controller itself: the withdraw over a second connection stalls too
    with pytest.raises(InstrumentLinkLost, match=r"did not answer Signals.ValsGet within 500 ms: the link stalled; "
                                                 r"it is closed; securing the tip \(withdraw\) failed too: .* did not "
                                                 "answer ZCtrl.Withdraw .* the tip was left where it was"):
        nanonis.read()
    with pytest.raises(InstrumentLinkLost, match="reopen the instrument"):
        nanonis.move_to((6e-6, 6e-6, math.nan))
    assert sim.instrument.tip_xy.tolist() == [X0, Y0]  # the move was never sent
    # a late reply can never be read as the answer to a later command: reopening starts afresh
    sim.faults.stall_after = None
    nanonis.close()
    nanonis.open()
    assert nanonis.read().position[0] == pytest.approx(X0, rel=1e-6)


def test_a_dead_link_raises_at_once(nanonis, sim):
    sim.faults.close_after = 0
    with pytest.raises(InstrumentLinkLost, match="closed the connection while answering Signals.ValsGet"):
        nanonis.read()


@pytest.mark.parametrize("kind, match", [("name", "answered 'ZCtrl.ZPosGet' to Signals.ValsGet: the replies are "
                                                  "out of step"),
                                         ("size", "body size 2147483647 bytes is outside"),
                                         ("truncated", "closed the connection")])
def test_garbled_replies_close_the_link(nanonis, sim, kind, match):
    sim.faults.corrupt = kind
    with pytest.raises(InstrumentLinkLost, match=match):
        nanonis.read()
    assert nanonis.link.lost is not None


def test_a_request_that_is_not_the_protocol_closes_the_connection(sim):
    link = NanonisConnection(*sim.address, timeout=1.0)
    link.open()
    with pytest.raises(InstrumentLinkLost, match="closed the connection"):
        link.request("ZCtrl.ZPosGet", b"ZCtrl.ZPosGet".ljust(32, b"\0") + struct.pack(">iHH", -5, 1, 0))
    link.open()
    with pytest.raises(ControllerError, match="'Bogus.Cmd' is not implemented by the simulated controller"):
        body = link.request("Bogus.Cmd", b"Bogus.Cmd".ljust(32, b"\0") + struct.pack(">iHH", 0, 1, 0))
        proto.decode_reply("FolMe.Stop", body)
    link.close()


# ---------------------------------------------------------------------------------------------
# the vendor's timing (Tap), the names list, the tip after a lost link


def test_tap_is_read_at_open_and_sets_the_sample_age_limit(sim):
    """Util.AcqPeriodGet at open; Util.AcqPeriodSet when asked; the sample-age limit covers Tap/2
    (the middle of the oversampled window) + the ValsGet wait (up to Tap) + three round trips."""
    with NanonisAFM(*sim.address, limits=LIMITS) as n:
        assert n.acquisition_period == pytest.approx(0.02, rel=1e-6) and sim.requests["Util.AcqPeriodGet"] == 1
        assert n.round_trip >= sim.latency
        assert n.sample_age_limit("xyz") >= 3.0 * (1.5 * 0.02 + 3 * sim.latency)
        assert n.sample_age_limit("xy") < n.sample_age_limit("xyz")
    with NanonisAFM(*sim.address, limits=LIMITS, acquisition_period=0.004) as n:
        assert sim.tap == pytest.approx(0.004, rel=1e-6) and n.acquisition_period == pytest.approx(0.004, rel=1e-6)
    with pytest.raises(InstrumentError, match="acquisition_period must be"):
        NanonisAFM(*sim.address, limits=LIMITS, acquisition_period=0.0)


def test_signals_valsget_waits_for_the_acquisition_period(sim):
    """The simulated controller answers ValsGet at the end of the current period of Tap: replies
    arrive on the period's grid, never faster than one per period."""
    import time

    sim.tap = 0.01
    with NanonisAFM(*sim.address, limits=LIMITS) as n:
        t = []
        for _ in range(6):
            n.read()
            t.append(time.perf_counter())
    gaps = np.diff(t)
    assert gaps.min() > 0.5 * sim.tap  # one reply per period at most


def test_names_size_is_tolerated_where_controllers_differ(sim):
    """A names array whose declared byte size counts only the strings (not their length prefixes)
    opens; a body with bytes left after the last name is still refused (strict where the protocol is)."""
    sim.names_size = "strings"
    with NanonisAFM(*sim.address, limits=LIMITS) as n:
        assert n.signal_names[0] == "X (m)"
    body = proto.encode_reply_body("Signals.NamesGet", (["a", "b"],)) + b"\0\0\0\0"
    with pytest.raises(InstrumentLinkLost, match="unexpected bytes"):
        proto.decode_reply("Signals.NamesGet", body)


def test_a_lost_link_withdraws_the_tip_over_a_second_connection(sim):
    """The first connection's network dies (the controller is fine): the read raises, and the tip
    is withdrawn over a new connection; with on_link_loss='hold' it is left where it was."""
    sim.faults.first_connection_only = True
    with NanonisAFM(*sim.address, limits=LIMITS, timeout=0.3) as n:
        sim.faults.stall_after = 0
        with pytest.raises(InstrumentLinkLost, match="the tip was withdrawn over a second connection"):
            n.read()
    assert sim.requests.get("ZCtrl.Withdraw") == 1
    with NanonisSimulator(_afm(), faults=Faults(first_connection_only=True)) as other:
        with NanonisAFM(*other.address, limits=LIMITS, timeout=0.3, on_link_loss="hold") as n:
            other.faults.stall_after = 0
            with pytest.raises(InstrumentLinkLost, match="the tip was left where it was"):
                n.read()
        assert "ZCtrl.Withdraw" not in other.requests
# scanning: Scan.Action, Scan.StatusGet / WaitEndOfScan, Scan.FrameGet / BufferGet / SpeedGet,
# Scan.FrameDataGrab


_SCAN_CASES = {
    "Scan.Action": ((0, 1), ()),
    "Scan.StatusGet": ((), (1,)),
    "Scan.WaitEndOfScan": ((5000,), (0, "C:/data/img001.sxm")),
    "Scan.FrameGet": ((), (1.5e-6, -2.5e-7, 1e-6, 5e-7, 0.0)),
    "Scan.BufferGet": ((), ([0, 14, 3], 256, 128)),
    "Scan.SpeedGet": ((), (2e-6, 4e-6, 0.5, 0.25, 0, 2.0)),
    "Scan.FrameDataGrab": ((0, 1), ("Z (m)", (np.arange(12.0).reshape(3, 4) - 5.0) * 1e-9, 1)),
}


@pytest.mark.parametrize("command", sorted(_SCAN_CASES))
def test_scan_commands_match_the_vendor_package_byte_for_byte(command):
    """Each request is the vendor's byte for byte, and the vendor's parser reads our reply as the
    values we encoded (its arrays as tuples, its 2-D frame as an array, its counts kept)."""
    nanonis_spm = _vendor()
    args, values = _SCAN_CASES[command]
    conn = _Capture(proto.encode_reply(command, values))
    error, _, parsed = getattr(nanonis_spm.Nanonis(conn), command.replace(".", "_"))(*args)
    assert conn.sent == proto.encode_request(command, args)
    assert error == ""
    ours = proto.decode_reply(command, proto.encode_reply_body(command, values))
    if command == "Scan.FrameDataGrab":
        size, name, rows, cols, data, up = parsed
        assert (size, name, rows, cols, up) == (5, "Z (m)", 3, 4, 1)
        assert np.asarray(data, dtype=np.float64) == pytest.approx(ours[1], rel=1e-7)
        assert ours[1] == pytest.approx(values[1], rel=1e-7)
    elif command == "Scan.WaitEndOfScan":
        assert parsed == [0, len(values[1]), values[1]] and ours == values
    elif command == "Scan.BufferGet":
        assert parsed[0] == 3 and [e[0] for e in parsed[1]] == values[0] and parsed[2:] == [256, 128]
        assert ours == (tuple(values[0]), 256, 128)
    else:
        assert tuple(parsed) == pytest.approx(values, rel=1e-7) and ours == pytest.approx(values, rel=1e-7)


def test_a_frame_reply_larger_than_other_replies_is_bounded():
    big = proto.encode_reply("Scan.FrameDataGrab", ("Z (m)", np.zeros((600, 600)), 1))
    assert len(big) - 40 > proto.MAX_BODY  # a 600 x 600 frame passes ...
    assert proto.parse_header(big[:40])[1] == len(big) - 40
    with pytest.raises(InstrumentLinkLost, match="outside"):  # ... a size beyond a 4096^2 frame does not
        proto.parse_header(big[:32] + struct.pack(">i", proto.MAX_FRAME_BODY + 1) + bytes(4))
    with pytest.raises(InstrumentLinkLost, match="outside"):  # nor a frame-sized body for another command
        proto.parse_header(proto.encode_reply("Scan.StatusGet", (0,))[:32] + struct.pack(">i", 2 * proto.MAX_BODY)
                           + bytes(4))
    body = proto.encode_reply_body("Scan.FrameDataGrab", ("Z", np.zeros((2, 2)), 1))
    lying = body[:5] + struct.pack(">ii", 1000, 1000) + body[13:]  # rows x cols beyond the bytes there
    with pytest.raises(InstrumentLinkLost, match="1000 x 1000"):
        proto.decode_reply("Scan.FrameDataGrab", lying)


def _scanning_afm():
    from arsurf.instrument.imaging import Sample, ScanSettings, ThermalDrift
    from arsurf.manipulation.nanotube import Nanotube
    from arsurf.scan.scan import Scan

    flat = Scan(np.zeros((100, 100)), dx=10e-9, dy=10e-9)
    tube = Nanotube(400e-9, 12e-9, x=500e-9, y=450e-9, angle=0.5)
    return _afm(sample=Sample(flat, objects=[tube]), drift=ThermalDrift(rate_xy=0.05e-9, seed=1),
                scan_settings=ScanSettings((64, 48), (640e-9, 480e-9), origin=(150e-9, 200e-9)))


@pytest.mark.parametrize("direction", ["up", "down"])
def test_a_scan_through_the_simulated_controller_is_the_virtual_afms_image(direction):
    """End to end: NanonisAFM.scan_image starts the scan over TCP, waits for its end and grabs the
    frame; the Scan is the virtual AFM's image (to float32), row 0 at the bottom either way, with
    the frame's geometry."""
    afm = _scanning_afm()
    with NanonisSimulator(afm) as sim, NanonisAFM(*sim.address, limits=LIMITS, timeout=0.5,
                                                  scan_direction=direction) as n:
        scan = n.scan_image()
        truth = sim.frame
        assert sim.requests["Scan.Action"] == 1 and sim.requests["Scan.FrameDataGrab"] == 1
        assert sim.frame_settings.direction == direction
    assert scan.shape == (48, 64) and scan.dx == pytest.approx(10e-9) and scan.dy == pytest.approx(10e-9)
    assert scan.heights == pytest.approx(truth.heights, abs=1e-15, rel=1e-6)
    assert scan.metadata["format"] == "nanonis-tcp" and scan.metadata["z_unit"] == "m"
    assert scan.metadata["instrument"]["origin_m"] == pytest.approx([150e-9, 200e-9], rel=1e-6)  # float32 frame
    assert scan.metadata["rows_flipped"] == (direction == "down")
    assert scan.heights.max() == pytest.approx(12e-9, abs=1.5e-9)  # the tube is there


def test_the_vendor_client_scans_through_the_simulator(sim):
    nanonis_spm = _vendor()
    sim.instrument._imaging = _scanning_afm()._imaging
    s = socket.create_connection(sim.address, timeout=5.0)
    try:
        client = nanonis_spm.Nanonis(s)
        client.Scan_Action(0, 1)
        err, _, (timed_out, _, _) = client.Scan_WaitEndOfScan(10000)
        assert err == "" and timed_out == 0
        err, _, (_, name, rows, cols, data, up) = client.Scan_FrameDataGrab(0, 1)
        assert (name, rows, cols, up) == ("Z (m)", 48, 64, 1)
        assert np.asarray(data, dtype=float) == pytest.approx(sim.frame.heights, abs=1e-15, rel=1e-6)
        err, _, _ = client.Scan_FrameDataGrab(0, 0)
        assert "forward" in err
    finally:
        s.close()


def test_scan_faults_are_one_line(sim):
    with NanonisAFM(*sim.address, limits=LIMITS, timeout=0.5) as n:
        with pytest.raises(ControllerError, match="no sample"):  # the flat number surface cannot be imaged
            n.scan_image()
        with pytest.raises(InstrumentError, match="without settings"):
            n.scan_image(object())
    with NanonisSimulator(_scanning_afm()) as s2:
        s2.scan_channels = {0: "Current (A)"}
        with NanonisAFM(*s2.address, limits=LIMITS, timeout=0.5) as n:
            with pytest.raises(InstrumentError, match="not the height"):
                n.scan_image()
        with NanonisAFM(*s2.address, limits=LIMITS, timeout=0.5, scan_channel=3) as n:
            with pytest.raises(InstrumentError, match="channel 3 is not one the scan records"):
                n.scan_image()
