"""Reading a damaged session never crashes, hangs or returns altered data: a small session file
and a killed recording's journal are mutated (bit flips, byte overwrites, truncations,
extensions, zeroed / copied / inserted blocks, fixed seed) and every mutant must either load
exactly as written or be refused with a SessionError. The big run is bench/fuzz_sessions.py."""
from __future__ import annotations

import numpy as np
import pytest

from arsurf.assembly import session_metadata
from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.errors import SessionError
from arsurf.force.cantilever import Cantilever
from arsurf.sessions.sealed import SEAL_SIZE, seal_bytes
from arsurf.sessions.journal import journal_path
from arsurf.sessions.reader import load_session
from arsurf.sessions.writer import SessionWriter

R = 20e-9
SCAN = {"path": "scans/sinusoid.npz", "sha256": "ab" * 32, "channel": None,
        "processing": {"level": "plane", "sigma": 2e-9, "inpaint": True}}


def _meta():
    return session_metadata(scan=SCAN, tip_radius=R, contact=MaugisDugdale(R, 50e9, 0.1),
                            cantilever=Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27), friction=0.25,
                            calibration={"gain": 1.5}, haptics={"device": "virtual"}, loop_rate=1000.0)


def _record(w, n, rng):
    for k in range(n):
        w.append(t=k * 1e-3, probe_position=rng.normal(size=3) * 1e-7, probe_velocity=rng.normal(size=3) * 1e-6,
                 force=rng.normal(size=3) * 1e-9, signals=rng.normal(size=2) * 1e-3, buttons=k % 3,
                 depth=float(rng.normal()) * 1e-9, md_status=k % 3 - 1, in_contact=k % 2)


def mutate(data: bytes, rng: np.random.Generator) -> bytes:
    """One random damage of ``data`` (never the identity)."""
    b = bytearray(data)
    n = len(b)
    op = int(rng.integers(8))
    if op == 0:  # one bit
        i = int(rng.integers(n))
        b[i] ^= 1 << int(rng.integers(8))
    elif op == 1:  # a few bits
        for i in rng.integers(n, size=int(rng.integers(2, 9))):
            b[int(i)] ^= 1 << int(rng.integers(8))
    elif op == 2:  # bytes overwritten
        i = int(rng.integers(n))
        k = int(rng.integers(1, 9))
        b[i:i + k] = rng.integers(256, size=len(b[i:i + k]), dtype=np.uint8).tobytes()
    elif op == 3:  # truncated
        del b[int(rng.integers(n)):]
    elif op == 4:  # extended
        b += rng.integers(256, size=int(rng.integers(1, 600)), dtype=np.uint8).tobytes()
    elif op == 5:  # a zeroed block
        i = int(rng.integers(n))
        b[i:i + 64] = bytes(len(b[i:i + 64]))
    elif op == 6:  # a block copied from elsewhere
        i, j = (int(x) for x in rng.integers(n, size=2))
        k = int(rng.integers(4, 256))
        b[i:i + k] = data[j:j + k][: len(b[i:i + k])]
    else:  # bytes inserted
        i = int(rng.integers(n))
        b[i:i] = rng.integers(256, size=int(rng.integers(1, 64)), dtype=np.uint8).tobytes()
    out = bytes(b)
    if out == data:  # a no-op (a block copied onto itself...): damage one bit instead
        b[0] ^= 1
        out = bytes(b)
    return out


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    d = tmp_path_factory.mktemp("fuzz")
    path = d / "s.h5"
    with SessionWriter(path, _meta(), created="2026-01-01T00:00:00+00:00") as w:
        _record(w, 40, np.random.default_rng(1))
    return path, load_session(path)


def _same(a, b) -> bool:
    return (a.n_ticks == b.n_ticks and a.metadata == b.metadata and a.attrs == b.attrs
            and a.ticks.keys() == b.ticks.keys()
            and all(a.ticks[k].dtype == b.ticks[k].dtype and a.ticks[k].tobytes() == b.ticks[k].tobytes()
                    for k in a.ticks))


def test_200_mutants_of_a_sealed_session_load_identical_or_are_refused(session, tmp_path):
    path, ref = session
    data = path.read_bytes()
    rng = np.random.default_rng(20261121)
    outcomes = {"identical": 0, "refused": 0}
    target = tmp_path / "m.h5"
    for i in range(200):
        target.write_bytes(mutate(data, rng))
        try:
            got = load_session(target)
        except SessionError:
            outcomes["refused"] += 1
            continue
        assert _same(got, ref), f"mutant {i} loaded with altered content"
        outcomes["identical"] += 1
    assert outcomes["refused"] == 200  # every damage of a sealed file is caught


def test_hdf5_damage_behind_a_valid_seal_is_refused_by_the_isolated_reader(session, tmp_path):
    """A file crafted to carry a valid seal over damaged HDF5 structures (what a seal cannot
    catch) reaches libhdf5 only in the isolated reader: refused, or identical, never a crash."""
    path, ref = session
    data = path.read_bytes()
    rng = np.random.default_rng(7)
    target = tmp_path / "m.h5"
    refused = 0
    for i in range(8):
        b = bytearray(data)
        for at in rng.integers(SEAL_SIZE, SEAL_SIZE + 4096, size=3):  # the signature too  # superblock, object headers, B-trees
            b[int(at)] ^= 1 << int(rng.integers(8))
        target.write_bytes(seal_bytes(bytes(b)))
        try:
            got = load_session(target, isolate=True)
        except SessionError:
            refused += 1
            continue
        assert _same(got, ref), f"resealed mutant {i} loaded with altered content"
    assert refused >= 1


def test_100_mutants_of_a_journal_give_a_prefix_or_are_refused(tmp_path):
    path = tmp_path / "j.h5"
    w = SessionWriter(path, _meta(), capacity=8, when_full="wait")
    _record(w, 80, np.random.default_rng(2))
    w._stream.stop()  # killed: no end record
    w._file.close()
    w._closed = True
    jp = journal_path(path)
    ref = load_session(jp, allow_incomplete=True)
    assert ref.n_ticks == 80
    data = jp.read_bytes()
    rng = np.random.default_rng(99)
    target = tmp_path / "m.h5.journal"
    counts = {"prefix": 0, "refused": 0}
    for i in range(100):
        target.write_bytes(mutate(data, rng))
        try:
            got = load_session(target, allow_incomplete=True)
        except SessionError:
            counts["refused"] += 1
            continue
        n = got.n_ticks
        assert n <= ref.n_ticks and n % 8 == 0 or n == ref.n_ticks, (i, n)
        assert got.metadata == ref.metadata, i
        for k in ref.ticks:
            assert got.ticks[k].tobytes() == ref.ticks[k][:n].tobytes(), (i, k)
        counts["prefix"] += 1
    assert counts["prefix"] > 0 and counts["refused"] > 0


@pytest.mark.parametrize("seed", range(4))
def test_hdf5_feature_mutants_of_a_resealed_session_are_refused(session, tmp_path, seed):
    """The ``hdf5_feature`` group of bench/fuzz_sessions.py, a seeded small sample: a feature
    planted in a random /ticks dataset, checksums and seal redone, is refused in-process."""
    import shutil

    import h5py
    from hdf5_attacks import KINDS as FEATURES
    from hdf5_attacks import plant, reseal_session

    rng = np.random.default_rng([20261127, seed])
    path = tmp_path / "f.h5"
    shutil.copy(session[0], path)
    with h5py.File(path, "r") as f:
        names = sorted(f["ticks"])
    feature = sorted(f for f in FEATURES if f != "external_storage_fifo")[int(rng.integers(len(FEATURES) - 1))]
    words = plant(path, "ticks/" + names[int(rng.integers(len(names)))], feature, tmp_path)
    reseal_session(path)
    with pytest.raises(SessionError, match=words):
        load_session(path)
