"""The bridge for any language: include/arsurf_bridge.h and the C++ client of examples/cpp/.

Compiled here (skipped, saying why, where no C or C++ compiler exists) and checked against the
Python implementations: SHA-256/HMAC against :mod:`hmac`, the documented test vector, every packet
byte for byte, the client's verdict on every kind of bad FORCE, the forces received for the same
poses in lockstep, tampered packets refused on both sides, authentication on a non-loopback
address, and a session driven by the C++ client through ``arsurf view --bridge-port --record``
that ``arsurf replay`` gives back bit for bit.
"""
from __future__ import annotations

import hashlib
import hmac
import json
import math
import os
import re
import shlex
import shutil
import socket
import struct
import subprocess
import sys
import threading
import time
import zlib
from pathlib import Path

import numpy as np
import pytest

import arsurf.haptics.client as client_mod
from arsurf.haptics.udp_bridge import (
    UdpBridgeDevice,
    decode_pose,
    encode_challenge,
    encode_force,
    encode_hello,
    encode_pose,
    encode_release,
    save_key,
)

ROOT = Path(__file__).resolve().parents[2]
HEADER = ROOT / "include" / "arsurf_bridge.h"
EXAMPLE = ROOT / "examples" / "cpp"
TOOL = ROOT / "tests" / "support" / "cpp" / "bridge_tool.c"
KEY = bytes(range(32))
OTHER_KEY = bytes(range(100, 132))
SID = bytes(range(0xF0, 0x100))  # a session id
LOOPBACK = "127.0.0.1"


def _compiler(env: str, names: tuple[str, ...], what: str) -> str:
    """The compiler named by ``env`` or the first of ``names`` installed; skip the test without one."""
    given = os.environ.get(env)
    if given and shutil.which(shlex.split(given)[0]):
        return given
    for name in () if given else names:
        if shutil.which(name):
            return name
    pytest.skip(f"no {what} compiler (set {env} or install {' or '.join(names[1:])}): "
                f"{'the C++ bridge client is not built' if env == 'CXX' else 'the header is not compiled as C'} here")


def _gnu_like(cc: str) -> bool:
    out = subprocess.run([*shlex.split(cc), "--version"], capture_output=True, text=True).stdout
    return bool(re.search(r"gcc|g\+\+|clang|Free Software Foundation", out, re.IGNORECASE))


@pytest.fixture(scope="session")
def cxx():
    return _compiler("CXX", ("c++", "g++", "clang++"), "C++")


@pytest.fixture(scope="session")
def cc():
    return _compiler("CC", ("cc", "gcc", "clang"), "C")


def _run(cmd, **kw):
    r = subprocess.run(cmd, capture_output=True, text=True, **kw)
    assert r.returncode == 0, f"{cmd} failed ({r.returncode}):\n{r.stdout}\n{r.stderr}"
    return r


def _readme_command() -> list[str]:
    """The one-line build command of examples/cpp/README.md."""
    for line in (EXAMPLE / "README.md").read_text().splitlines():
        if line.startswith("g++ "):
            return shlex.split(line)
    raise AssertionError("examples/cpp/README.md has no one-line g++ command")


@pytest.fixture(scope="session")
def client_exe(cxx, tmp_path_factory):
    """The C++ client built with the README's one-line command (the compiler found here for g++)."""
    exe = tmp_path_factory.mktemp("cpp") / "arsurf_client"
    cmd = _readme_command()
    cmd = [*shlex.split(cxx), *cmd[1:]]
    cmd[cmd.index("-o") + 1] = str(exe)
    _run(cmd, cwd=EXAMPLE)
    return str(exe)


@pytest.fixture(scope="session")
def tool(cc, tmp_path_factory):
    """tests/support/cpp/bridge_tool.c built as C99 (the header is plain C)."""
    exe = tmp_path_factory.mktemp("ctool") / "bridge_tool"
    _run([*shlex.split(cc), "-std=c99", "-O2", "-ffp-contract=off", f"-I{ROOT / 'include'}", str(TOOL), "-o", str(exe),
          "-lm"])

    def run(mode: str, lines: list[str]) -> list[str]:
        r = _run([str(exe), mode], input="".join(f"{x}\n" for x in lines))
        return r.stdout.splitlines()

    return run


def bits(x: float) -> str:
    return struct.pack("<d", x)[::-1].hex()  # big-endian hex of the IEEE-754 bits


def from_bits(h: str) -> float:
    return struct.unpack(">d", bytes.fromhex(h))[0]


def key_file(tmp_path, key=KEY, name="bridge.key") -> str:
    return save_key(tmp_path / name, key)


# ---------------------------------------------------------------------------------------------
# the header
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("lang", ["c99", "c++11"])
def test_the_header_compiles_warning_free_as_c_and_cxx(lang, cc, cxx, tmp_path):
    compiler = cc if lang == "c99" else cxx
    if not _gnu_like(compiler):
        pytest.skip(f"{compiler} is not gcc or clang: the warning flags tested are theirs")
    src = tmp_path / ("t.c" if lang == "c99" else "t.cpp")
    src.write_text('#include "arsurf_bridge.h"\nint main(void) { return arsurf_self_test(); }\n')
    r = _run([*shlex.split(compiler), f"-std={lang}", "-Wall", "-Wextra", "-pedantic", "-Werror", "-Wshadow",
              "-Wconversion", f"-I{ROOT / 'include'}", str(src), "-o", str(tmp_path / "t"), "-lm"])
    assert r.stderr == ""
    assert subprocess.run([str(tmp_path / "t")]).returncode == 0  # the self-test passes on this platform


def _doc_vectors() -> dict[str, bytes]:
    text = (ROOT / "docs" / "bridge-protocol.rst").read_text()
    found: dict[str, bytes] = {}
    for name, part, data in re.findall(r"^\s*(\w+)\.(body|tag)\s+(?:[0-9a-f]{4}:)?\s*([0-9a-f ]+)$", text, re.MULTILINE):
        found[name] = found.get(name, b"") + bytes.fromhex(data.replace(" ", ""))
    return found


def test_the_documented_test_vector(tool, client_exe):
    doc = _doc_vectors()
    out = dict(line.split(" ", 1) for line in tool("vector", []))
    for name in ("hello", "challenge", "pose", "force", "release"):
        assert bytes.fromhex(out[name]) == doc[name], name
    assert out["self_test"] == "0"
    r = _run([client_exe, "--self-test"])
    assert json.loads(r.stdout) == {"self_test": "ok", "failed_check": 0}


def test_hmac_sha256_matches_pythons(tool):
    """Every key length (empty, shorter than, equal to and longer than the 64-byte block: hashed)
    and message lengths across the padding boundaries (55, 56, 63, 64, 65...)."""
    rng = np.random.default_rng(16)
    cases = []
    for klen in (0, 1, 16, 32, 63, 64, 65, 100, 200):
        for mlen in (0, 1, 55, 56, 57, 63, 64, 65, 108, 119, 120, 128, 300, 1000):
            cases.append((rng.bytes(klen), rng.bytes(mlen)))
    got = tool("hmac", [f"{k.hex() or '-'} {m.hex() or '-'}" for k, m in cases])
    want = [hmac.new(k, m, hashlib.sha256).hexdigest() for k, m in cases]
    assert got == want


def _random_double(rng) -> float:
    kind = rng.integers(8)
    if kind == 0:
        return float(rng.choice([0.0, -0.0, math.inf, -math.inf, math.nan, 5e-324, -1.7976931348623157e308]))
    if kind == 1:  # any bit pattern at all (NaN payloads, subnormals)
        return struct.unpack("<d", rng.bytes(8))[0]
    return float(rng.normal() * 10.0 ** rng.integers(-12, 3))


def test_packets_byte_for_byte_with_python(tool):
    rng = np.random.default_rng(7)
    lines, want = [], []
    for k in range(300):
        key = rng.bytes(int(rng.integers(16, 65)))
        edges = [0, 1, 2**32 - 1, 2**32, 2**63, 2**64 - 1, int(rng.integers(0, 2**63))]
        seq = edges[int(rng.integers(len(edges)))]
        t, d = _random_double(rng), [_random_double(rng) for _ in range(10)]
        buttons = int(rng.integers(0, 2**32))
        sid = rng.bytes(16)
        lines.append(f"pose {key.hex()} {seq} {sid.hex()} {bits(t)} " + " ".join(bits(x) for x in d) + f" {buttons}")
        a = encode_pose(key, seq, t, d[0:3], d[3:6], d[6:10], buttons, session=sid)
        b = client_mod.encode_pose(key, seq, t, d[0:3], d[3:6], d[6:10], buttons, session=sid)
        assert a == b
        want.append(a.hex())
        lines.append(f"release {key.hex()} {seq} {sid.hex()} {bits(t)}")
        want.append(encode_release(key, seq, t, session=sid).hex())
        lines.append(f"hello {key.hex()} {seq} {bits(t)}")
        want.append(encode_hello(key, seq, t).hex())
        ack, flags = int.from_bytes(rng.bytes(8), "little"), int(rng.integers(0, 2**16))
        lines.append(f"challenge {key.hex()} {seq} {ack} {sid.hex()}")
        want.append(encode_challenge(key, seq, ack, sid).hex())
        lines.append(f"force {key.hex()} {seq} {sid.hex()} {ack} {bits(d[0])} {bits(d[1])} "
                     + " ".join(bits(x) for x in d[2:5]) + f" {flags}")
        want.append(encode_force(key, seq, ack, d[0], d[1], d[2:5], flags, session=sid).hex())
    assert tool("encode", lines) == want


def _verdicts_python(key, start_seq, poses, max_force, challenge, datagrams):
    """The Python reference client's verdicts (HapticClient._check) on the same datagrams, after
    one HELLO answered by ``challenge`` and ``poses`` poses."""
    c = client_mod.HapticClient(LOOPBACK, 9, key, max_force=max_force)
    try:
        c.seq, c.first_seq = start_seq + 1, start_seq + 1
        server = c.server
        assert c._check(challenge, server) is None and c.stats["challenges"] == 1
        c.seq += poses
        out = []
        for from_server, data in datagrams:
            before = dict(c.stats)
            reply = c._check(data, server if from_server else ("127.0.0.9", 1))
            if reply is not None:
                out.append("accepted " + " ".join(bits(v) for v in reply["force"]))
            else:
                changed = [k for k in client_mod.DROP_REASONS if c.stats[k] != before[k]]
                assert len(changed) == 1
                out.append(changed[0])
        return out
    finally:
        c.sock.close()


def test_the_client_checks_decide_as_the_python_client(tool):
    """Seeded sequences of good, tampered, replayed, reordered, foreign, late, non-finite and
    over-limit FORCE datagrams: the C checks give the same verdict, in the same order of checks,
    and the same force bits as HapticClient."""
    rng = np.random.default_rng(3)
    for trial in range(25):
        key = rng.bytes(32)
        start, poses = int(rng.integers(1, 2**62)), int(rng.integers(1, 50))
        first, last = start + 1, start + 1 + poses  # one HELLO, then the poses
        sid = rng.bytes(16)
        challenge = encode_challenge(key, 0, first, sid)
        max_force = float(rng.choice([7.9, 1.0, 3.3]))
        seq = int(rng.integers(0, 2**62))
        accepted = []
        datagrams = []

        def force(s, f, ack=None, t=0.5, k=key, session=sid):
            return encode_force(k, s, last if ack is None else ack, t, 0.25, f, session=session)

        for _ in range(60):
            kind = int(rng.integers(17))
            seq += int(rng.integers(1, 4))
            f = tuple(float(x) for x in rng.normal(size=3) * max_force / 3)
            good = force(seq, f, ack=int(rng.integers(first, last + 1)))
            if kind == 0:
                p = good[:rng.integers(0, 112)]
            elif kind == 1:
                p = good + rng.bytes(int(rng.integers(1, 50)))
            elif kind == 2:  # one flipped bit anywhere
                b = bytearray(good)
                b[int(rng.integers(112))] ^= 1 << int(rng.integers(8))
                p = bytes(b)
            elif kind == 3:
                p = force(seq, f, k=OTHER_KEY)
            elif kind == 4 and accepted:  # replay of an accepted one, or an older number
                p = accepted[int(rng.integers(len(accepted)))] if rng.integers(2) else force(seq - 100, f)
            elif kind == 5:
                acks = [first - 1, last + 1, 0, 2**64 - 1]
                p = force(seq, f, ack=acks[int(rng.integers(len(acks)))])
            elif kind == 6:
                p = force(seq, (f[0], math.nan, f[2])) if rng.integers(2) else force(seq, f, t=math.inf)
            elif kind == 7:  # over the limit, at it, and just above its tolerance
                lim = max_force * float(rng.choice([1.0, 1.0 + 1e-9, 1.0 + 2e-9, 1.5]))
                p = force(seq, (0.0, 0.0, lim))
            elif kind == 8:
                p = encode_pose(key, seq, 0.0, (0.0, 0.0, 0.0), session=sid)[:112]
            elif kind == 9:
                body = struct.pack("<4sBBHIIdd3d", b"ARSH", 1, 2, 0, seq & 0xFFFFFFFF, 0, 0.5, 0.0, 0.0, 0.0, 1.0)
                p = body + struct.pack("<I", zlib.crc32(body))
            elif kind == 10:
                p = b"XRSH" + good[4:]
            elif kind == 11:  # a FORCE of another session, or a CHALLENGE recorded in an earlier run
                p = force(seq, f, session=rng.bytes(16)) if rng.integers(2) else encode_challenge(key, seq, first - 1,
                                                                                                  rng.bytes(16))
            else:
                p = good
            from_server = int(rng.integers(12) != 0)
            datagrams.append((from_server, p))
            if from_server and p == good and kind > 11:
                accepted.append(good)
        lines = [f"client {key.hex()} {start} 1 {bits(max_force)}", f"1 {challenge.hex()}", f"poses {poses}"]
        lines += [f"{fs} {p.hex() or '-'}" for fs, p in datagrams]
        got = tool("check", lines)
        assert got[:3] == [f"client {first} {first}", "challenges", str(last)], got[:3]
        got = got[3:]
        want = _verdicts_python(key, start, poses, max_force, challenge, datagrams)
        assert got == want, trial
        assert "accepted" in " ".join(got) and "bad_mac" in got


# ---------------------------------------------------------------------------------------------
# the client on the wire
# ---------------------------------------------------------------------------------------------
def _udp(host=LOOPBACK):
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind((host, 0))
    return s


def test_the_client_refuses_bad_key_files_and_arguments(client_exe, tmp_path):
    good = key_file(tmp_path)
    shared = tmp_path / "shared.key"
    shared.write_text(KEY.hex() + "\n")
    os.chmod(shared, 0o644)
    short = tmp_path / "short.key"
    short.write_text("ab" * 8)  # 8 bytes
    os.chmod(short, 0o600)
    for args, needle in (([], "--key-file"), (["--key-file", str(shared)], "other users"),
                         (["--key-file", str(short)], "does not hold a key"),
                         (["--key-file", str(tmp_path / "missing")], "cannot read"),
                         (["--key-file", good, "--rate", "abc"], "--rate"),
                         (["--key-file", good, "--bogus"], "unknown argument")):
        r = subprocess.run([client_exe, *args], capture_output=True, text=True)
        assert r.returncode == 2, (args, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1 and needle in r.stderr, r.stderr
        assert KEY.hex() not in r.stderr
    if os.name == "posix" and os.geteuid() == 0:  # files a second user could have planted (as root: chown)
        from tests.support.bridge_keys import _planted_key_files

        for path, needle in _planted_key_files(tmp_path / "planted"):
            r = subprocess.run([client_exe, "--key-file", str(path)], capture_output=True, text=True, timeout=10)
            assert r.returncode == 2, (path, r.stderr)
            assert len(r.stderr.strip().splitlines()) == 1, r.stderr
            assert needle in r.stderr or "cannot read" in r.stderr, (path, r.stderr)


@pytest.mark.skipif(os.name != "posix" or os.geteuid() != 0, reason="planting a file as another user needs root")
def test_the_header_refuses_key_files_someone_else_could_have_planted(tool, tmp_path):
    """arsurf_read_key_file judges a key file as load_key does (and ssh a private key): a good one
    is read; a foreign-owned one, one in a folder others can write to or own, a link, a FIFO
    (without blocking) and a directory are refused with one line naming the rule."""
    from tests.support.bridge_keys import _planted_key_files

    good = key_file(tmp_path)
    planted = _planted_key_files(tmp_path / "planted")
    out = tool("keyfile", [good] + [str(p) for p, _ in planted])
    assert out[0] == f"ok {KEY.hex()}"
    for line, (path, needle) in zip(out[1:], planted):
        assert line.startswith("error ") and (needle in line or "cannot read" in line), (path, line)


@pytest.mark.realtime
def test_tampered_forces_never_reach_the_hand_on_the_wire(client_exe, tmp_path):
    """A stand-in server answers every POSE with one good FORCE and eleven bad ones (and a
    stranger sends one too): the client applies the good ones only and counts every bad one by
    its reason. The POSE datagrams it sends are, byte for byte, the Python encoder's."""
    srv, intruder = _udp(), _udp()
    srv.settimeout(10.0)
    rounds, poses_ok, first, released = [0], [True], [None], [False]

    def serve():
        seq = 1000
        while True:
            try:
                data, addr = srv.recvfrom(4096)
            except socket.timeout:
                return
            if data[5] == 4:  # HELLO: the session id
                poses_ok[0] &= data == encode_hello(KEY, struct.unpack_from("<Q", data, 8)[0],
                                                    struct.unpack_from("<d", data, 32)[0])
                seq += 1
                srv.sendto(encode_challenge(KEY, seq, struct.unpack_from("<Q", data, 8)[0], SID), addr)
                continue
            if data[5] == 3:  # RELEASE
                poses_ok[0] &= data == encode_release(KEY, struct.unpack_from("<Q", data, 8)[0],
                                                      struct.unpack_from("<d", data, 32)[0], session=SID)
                released[0] = True
                return
            p = decode_pose(KEY, data)
            poses_ok[0] &= p is not None and data == encode_pose(KEY, p["seq"], p["t"], p["position"], p["velocity"],
                                                                 p["quaternion"], p["buttons"], session=SID)
            ack = p["seq"]
            first[0] = first[0] or ack
            seq += 20
            def force(s, a, f, session=SID, key=KEY):
                return encode_force(key, s, a, 1.0, p["t"], f, session=session)

            good = force(seq, ack, (0.0, 0.0, 1.0))
            flipped = bytearray(force(seq + 1, ack, (0.0, 0.0, 5.0)))
            flipped[76] ^= 0x10
            bad = [bytes(flipped),                                                   # bad_mac
                   force(seq + 2, ack, (0.0, 0.0, 5.0), key=OTHER_KEY),              # bad_mac
                   good,                                                             # replayed
                   force(seq - 10, ack, (0.0, 0.0, 5.0)),                            # out_of_order
                   force(seq + 3, first[0] - 2, (0.0, 0.0, 5.0)),                    # bad_ack
                   force(seq + 4, ack, (math.nan, 0.0, 5.0)),                        # nonfinite
                   force(seq + 5, ack, (0.0, 0.0, 7.91)),                            # over_limit
                   force(seq + 7, ack, (0.0, 0.0, 5.0), session=SID[::-1]),          # bad_session
                   good[:111], good + b"\0", b"XRSH" + good[4:], data[:112]]         # truncated .. bad_type
            srv.sendto(good, addr)
            for b in bad:
                srv.sendto(b, addr)
            intruder.sendto(force(seq + 6, ack, (0.0, 0.0, 6.0)), addr)  # foreign
            rounds[0] += 1

    th = threading.Thread(target=serve)
    th.start()
    try:
        r = _run([client_exe, "--port", str(srv.getsockname()[1]), "--key-file", key_file(tmp_path), "--rate", "200",
                  "--duration", "0.2", "--lockstep", "--max-force", "7.9"], timeout=60)
    finally:
        th.join(15)
        srv.close()
        intruder.close()
    s = json.loads(r.stdout)
    n = rounds[0]
    assert s["ticks"] == 40 and s["hellos"] == 1 and n == 39  # the first tick said HELLO
    assert s["lockstep_timeouts"] == 0 and poses_ok[0] and released[0]
    assert s["accepted_replies"] == n and s["max_force_N"] == 1.0  # no 5, 6, 7.91 N or NaN ever applied
    assert s["dropped_replies"] == {"bad_mac": 2 * n, "replayed": n, "out_of_order": n, "bad_ack": n,
                                    "nonfinite": n, "over_limit": n, "truncated": n, "oversized": n,
                                    "bad_magic": n, "bad_type": n, "foreign": n, "bad_session": n}


class FakeClock:
    def __init__(self):
        self.t = 50.0

    def __call__(self):
        return self.t


def _bridge_model():
    from arsurf.assembly import PRESETS, make_model
    from arsurf.spline.surface import BSplineSurface

    x = np.arange(60) * 4e-9
    heights = 4e-9 * np.sin(2 * np.pi * x / 80e-9)[None, :] * np.cos(2 * np.pi * x / 120e-9)[:, None]
    s = BSplineSurface.from_heights(heights, (0.0, x[-1]), (0.0, x[-1]))
    p = PRESETS["viewer"]
    return make_model(s, tip_radius=20e-9, effective_modulus=p.effective_modulus, work_of_adhesion=p.work_of_adhesion)


class LockstepServer:
    """The bridge and the loop of ``arsurf view --bridge-port`` stepped once per accepted POSE on
    a clock that advances 1 ms per tick: the forces depend on the poses only."""

    def __init__(self, host=LOOPBACK, key=KEY):
        from arsurf.assembly import BRIDGE_HAPTICS, build_loop
        from arsurf.haptics.live_loop import bridge_start

        self.clock = FakeClock()
        self.dev = UdpBridgeDevice(host, 0, key=key, clock=self.clock).open()
        model = _bridge_model()
        self.loop = build_loop(model, BRIDGE_HAPTICS, self.dev.info, bridge_start(model.surface, model.tip_radius))
        self.sent = []
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run)
        self.thread.start()

    @property
    def port(self):
        return self.dev.address[1]

    def _run(self):
        dev = self.dev
        while not self.stop.is_set() and dev.stats.releases == 0:
            if dev.poll() == 0:
                time.sleep(5e-5)
                continue
            state = dev.read_state()
            f = self.loop.step(state, dev.now())
            dev.command_force(f)
            self.sent.append(tuple(dev._force * dev.force_gain))
            self.clock.t += 1e-3

    def close(self):
        self.stop.set()
        self.thread.join(10)
        self.dev.close()


def _read_log(path):
    rows = [line.split(",") for line in Path(path).read_text().splitlines()[1:]]
    pos = np.array([[float(v) for v in r[3:6]] for r in rows])
    vel = np.array([[float(v) for v in r[6:9]] for r in rows])
    force = np.array([[float(v) for v in r[9:12]] for r in rows])
    return pos, vel, force


@pytest.mark.realtime
def test_same_poses_same_forces_as_the_python_client(client_exe, tmp_path):
    """The C++ client in lockstep presses into a wavy surface and slides: the forces it receives
    are bit for bit those the loop sent, and the Python client sending the same poses to a fresh
    identical loop receives the same forces."""
    kf = key_file(tmp_path)
    server = LockstepServer()
    try:
        r = _run([client_exe, "--port", str(server.port), "--key-file", kf, "--lockstep", "--duration", "0.3",
                  "--radius", "0.002", "--frequency", "3", "--press", "0.004", "--log", str(tmp_path / "c.csv")],
                 timeout=120)
    finally:
        server.close()
    s = json.loads(r.stdout)
    assert s["lockstep_timeouts"] == 0 and s["invalid_replies"] == 0 and s["ticks"] == 300 and s["hellos"] == 1
    pos, vel, cpp_force = _read_log(tmp_path / "c.csv")
    pos, vel, cpp_force = pos[1:], vel[1:], cpp_force[1:]  # the first tick said HELLO
    sent = np.array(server.sent)
    assert sent.shape == (299, 3)
    np.testing.assert_array_equal(cpp_force, sent)  # every reply applied, as sent
    assert np.count_nonzero(np.linalg.norm(sent, axis=1) > 1e-4) > 50  # pressed in: the hand feels the surface
    assert np.ptp(sent[:, 0]) > 0 and np.ptp(sent[:, 1]) > 0  # and its slopes, sideways

    server = LockstepServer()
    c = client_mod.HapticClient(LOOPBACK, server.port, KEY)
    py_force = []
    try:
        c.hello()
        deadline = time.monotonic() + 5.0
        while c.session is None:
            c.poll()
            assert time.monotonic() < deadline, "no CHALLENGE"
        for p, v in zip(pos, vel):
            seq = c.send_pose(p, v)
            deadline = time.monotonic() + 5.0
            while not (c.last_reply and c.last_reply[1]["ack"] >= seq):
                c.poll()
                assert time.monotonic() < deadline, "no reply in lockstep"
            py_force.append(c.force)
    finally:
        c.close()
        server.close()
    np.testing.assert_array_equal(np.array(py_force), cpp_force)


def test_tampered_poses_from_the_c_encoder_are_refused(tool):
    """Every byte of a C-encoded POSE flipped: the bridge accepts none of them, nothing moves;
    the untouched packet is accepted."""
    p = [0.01, -0.02, 0.03]
    with UdpBridgeDevice(LOOPBACK, 0, key=KEY) as dev, _udp() as s:
        line = (f"pose {KEY.hex()} 77 {dev.session.hex()} {bits(0.5)} " + " ".join(bits(x) for x in [*p, 0, 0, 0, 1, 0, 0, 0])
                + " 1")
        pkt = bytes.fromhex(tool("encode", [line])[0])
        for i in range(len(pkt)):
            bad = bytearray(pkt)
            bad[i] ^= 0x01
            s.sendto(bytes(bad), dev.address)
        s.sendto(pkt, dev.address)
        deadline = time.monotonic() + 5.0
        while dev.stats.received < len(pkt) + 1 and time.monotonic() < deadline:
            dev.poll()
            time.sleep(1e-3)
        st = dev.stats
        assert st.received == len(pkt) + 1 and st.accepted == 1 and st.pins == 1
        assert st.dropped == len(pkt) and st.bad_session == 16  # the session id's bytes
        assert st.bad_mac >= len(pkt) - 16 - 8  # header flips: magic/version/type
        assert dev.read_state().position.tolist() == p


def _lan_address() -> str | None:
    """This machine's address on its network (not loopback), or None."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("192.0.2.1", 9))  # TEST-NET: nothing is sent
            addr = s.getsockname()[0]
        except OSError:
            return None
    return None if addr.startswith("127.") or addr == "0.0.0.0" else addr


@pytest.mark.realtime
def test_beyond_loopback_only_with_the_key(client_exe, tmp_path, capsys):
    """--host beyond loopback: refused without a key given by the operator; with one, the C++
    client reaching the bridge over the machine's network address is served, a client with
    another key is not (counted, never pinned)."""
    from arsurf.cli import main
    from arsurf.errors import HapticsError

    assert main(["view", "--bridge-port", "0", "--host", "0.0.0.0", "--frames", "0"]) == 2
    assert "not loopback" in capsys.readouterr().err
    with pytest.raises(HapticsError, match="needs a key"):
        UdpBridgeDevice("0.0.0.0", 0)
    lan = _lan_address()
    if lan is None:
        pytest.skip("this machine has no network address besides loopback")
    server = LockstepServer(host="0.0.0.0")
    try:
        wrong = subprocess.run([client_exe, "--host", lan, "--port", str(server.port), "--key-file",
                                key_file(tmp_path, OTHER_KEY, "other.key"), "--wait", "0.5", "--duration", "0.05"],
                               capture_output=True, text=True, timeout=60)
        assert wrong.returncode == 3 and "no valid reply" in wrong.stderr
        assert server.dev.stats.bad_mac > 0 and server.dev.stats.pins == 0 and server.sent == []
        r = _run([client_exe, "--host", lan, "--port", str(server.port), "--key-file", key_file(tmp_path),
                  "--lockstep", "--duration", "0.05"], timeout=60)
        server.thread.join(5.0)  # the client's last packet, RELEASE, may still be in the socket: the server ends on it
    finally:
        server.close()
    s = json.loads(r.stdout)
    assert s["accepted_replies"] == 49 and s["invalid_replies"] == 0 and s["hellos"] >= 1  # tick 1: HELLO
    assert server.dev.stats.pins == 1 and server.dev.stats.releases == 1 and len(server.sent) == 49


def test_cmake_builds_the_example(cxx, tmp_path):
    if shutil.which("cmake") is None:
        pytest.skip("cmake is not installed: the CMakeLists.txt of examples/cpp is not built here")
    env = dict(os.environ, CXX=shutil.which(shlex.split(cxx)[0]))
    _run(["cmake", "-S", str(EXAMPLE), "-B", str(tmp_path / "build")], env=env)
    _run(["cmake", "--build", str(tmp_path / "build")], env=env)
    r = _run([str(tmp_path / "build" / "arsurf_client"), "--self-test"])
    assert json.loads(r.stdout)["self_test"] == "ok"


# ---------------------------------------------------------------------------------------------
# end to end: a recorded session, replayed
# ---------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_a_cpp_client_drives_a_recorded_session_that_replays_bit_for_bit(client_exe, tmp_path):
    """`arsurf view --bridge-port 0 --record FILE --frames 0` serves the C++ client until its
    RELEASE; the session holds the poses it sent, and `arsurf replay` gives back its forces
    and contacts bit for bit."""
    from arsurf.assembly import BRIDGE_HAPTICS, BUNDLED_SCAN
    from arsurf.cli import main
    from arsurf.sessions.reader import load_session

    session, kf, log = tmp_path / "run.h5", tmp_path / "bridge.key", tmp_path / "server.err"
    with open(log, "w") as err:
        server = subprocess.Popen([sys.executable, "-m", "arsurf", "view", "--bridge-port", "0", "--bridge-key-file",
                                   str(kf), "--record", str(session), "--frames", "0"],
                                  stdout=subprocess.PIPE, stderr=err, text=True)
    try:
        deadline, port = time.monotonic() + 300.0, None
        while port is None:  # the model is built, the port bound: the key file is there too
            m = re.search(r"running at 1 kHz, listening .* on UDP 127\.0\.0\.1:(\d+)", log.read_text())
            port = int(m.group(1)) if m else None
            assert server.poll() is None and time.monotonic() < deadline, log.read_text()
            time.sleep(0.05)
        r = _run([client_exe, "--port", str(port), "--key-file", str(kf), "--wait", "60", "--duration", "1.0",
                  "--radius", "0.005", "--press", "0.004", "--log", str(tmp_path / "c.csv")], timeout=120)
        out, _ = server.communicate(timeout=120)  # it stops after the client's RELEASE
    finally:
        if server.poll() is None:
            server.kill()
            server.wait()
    assert server.returncode == 0, log.read_text()
    assert f"session recorded: {session}" in out
    s = json.loads(r.stdout)
    assert s["invalid_replies"] == 0 and s["accepted_replies"] > 0 and s["max_force_N"] <= 7.9

    rec = load_session(session)
    assert rec.complete and rec.verified and rec.n_ticks > 300
    # the bridge's settings, with the protections the loop ran with: the coupling of the bridge's device
    # (a Touch X: half its smallest stiffness limit, 740 N/m at 1 kHz) and the passivity controller
    from arsurf.haptics.gains import coupling_stiffness
    from arsurf.haptics.udp_bridge import UdpBridgeDevice

    k_vc = coupling_stiffness(UdpBridgeDevice().info, BRIDGE_HAPTICS["rate"])
    assert rec.metadata["device"]["interface"] == "udp-bridge"
    assert rec.metadata["haptics"] == dict(BRIDGE_HAPTICS, virtual_coupling=True, coupling_stiffness=k_vc, passivity=True)
    assert kf.read_text().strip() not in session.read_bytes().hex()  # the key is never recorded
    t = rec.ticks
    pos, _, applied = _read_log(tmp_path / "c.csv")
    sent = {tuple(p) for p in pos}
    stylus = t["stylus_position"]
    moved = np.any(stylus != 0.0, axis=1)
    assert moved.sum() > 200 and all(tuple(p) in sent for p in stylus[moved])  # the poses the client sent
    assert t["in_contact"].sum() > 100  # it pressed into the surface
    # what the client applied is what the loop commanded (times the bridge's stale-input ramp in [0, 1])
    dev = t["device_force"][np.linalg.norm(t["device_force"], axis=1) > 0]
    for f in applied[np.linalg.norm(applied, axis=1) > 0]:
        ratio = np.linalg.norm(f) / np.linalg.norm(dev, axis=1)
        cross = np.linalg.norm(np.cross(dev, f), axis=1) / (np.linalg.norm(dev, axis=1) * np.linalg.norm(f))
        assert np.any((cross < 1e-9) & (ratio <= 1.0 + 1e-12)), f

    out_dir = tmp_path / "replay"
    assert main(["replay", str(session), "--scan", str(BUNDLED_SCAN), "--out", str(out_dir), "-q"]) == 0
    summary = json.loads((out_dir / "summary.json").read_text())
    assert summary["n_ticks"] == rec.n_ticks and summary["contact_mismatches"] == 0
    assert summary["load_difference_N"] == 0.0 and summary["depth_difference_m"] == 0.0
    rows = np.genfromtxt(out_dir / "forces.csv", delimiter=",", names=True)
    for axis in "xyz":  # the loop's force on the tip, recomputed offline to the last bit
        np.testing.assert_array_equal(rows[f"F_recorded_{axis}_N"], rows[f"F_simulated_{axis}_N"])
    assert np.abs(rows["F_simulated_z_N"]).max() > 0
