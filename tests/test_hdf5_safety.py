"""An HDF5 file is only its own bytes: every HDF5 reader refuses what reaches outside them.

Each feature (tests/hdf5_attacks.py) is planted with h5py in a valid file of every HDF5-based
format (TopoStats, Nanosurf .nhf, JPK .h5-jpk, sessions, replay outputs); the reader must refuse
it in this process with one line naming the feature, and never return the
other file's bytes as data. A FIFO as the external target or as the file itself must not block.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from arsurf import load_scan
from arsurf._h5safe import MAX_EXPANSION, open_hdf5
from arsurf.errors import CorruptScan, ScanError, SessionError, UnsafeFile
from hdf5_attacks import KINDS, make_fifo, plant, reseal_session

from conftest import real_scan_path

DATA = Path(__file__).parent / "data"


class FifoGuard:
    """A child process that opens ``fifo`` for writing and closes it at once: a reader that
    wrongly opens the FIFO gets end-of-file instead of blocking the test run forever (so a test
    of a reader without the fix fails instead of hanging). Killed by its handle at the end."""

    def __init__(self, fifo: Path):
        self.proc = subprocess.Popen([sys.executable, "-c", f"open({str(fifo)!r}, 'wb').close()"])

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.proc.kill()
        self.proc.wait()


def _topostats(path: Path) -> tuple[Path, list[str]]:
    with h5py.File(path, "w") as f:
        f.create_dataset("image", data=np.arange(64, dtype=np.float64).reshape(8, 8) * 0.1)
        f.create_dataset("pixel_to_nm_scaling", data=2.0)
        f.create_dataset("topostats_file_version", data=0.2)
    return path, ["image", "pixel_to_nm_scaling"]


def _nhf(path: Path) -> tuple[Path, list[str]]:
    shutil.copy(DATA / "nanosurf_wavemode_excerpt.nhf", path)
    return path, ["measurement_0/segment_0/dataset_0"]


def _h5jpk(path: Path) -> tuple[Path, list[str]]:
    shutil.copy(real_scan_path("sample_0.h5-jpk"), path)
    return path, ["Measurement_000/Channel_001/Height"]


FORMATS = {"topostats": (".topostats", _topostats), "nhf": (".nhf", _nhf), "h5-jpk": (".h5-jpk", _h5jpk)}


def _refused(call, exc_type, words: str):
    """One line naming the feature (the time it takes is measured by bench/fuzz_readers.py and
    bench/fuzz_sessions.py, not asserted here)."""
    with pytest.raises(exc_type) as info:
        call()
    msg = str(info.value)
    assert "\n" not in msg, msg
    assert words in msg, msg
    return msg


@pytest.mark.parametrize("kind", sorted(KINDS))
@pytest.mark.parametrize("fmt", sorted(FORMATS))
def test_every_hdf5_scan_reader_refuses_every_feature(tmp_path, fmt, kind):
    ext, build = FORMATS[fmt]
    path, targets = build(tmp_path / f"scan{ext}")
    load_scan(path)  # the untouched file reads
    for target in targets:
        p = tmp_path / f"{target.replace('/', '_')}{ext}"
        shutil.copy(path, p)
        words = plant(p, target, kind, tmp_path)
        with FifoGuard(make_fifo(tmp_path)):
            msg = _refused(lambda: load_scan(p), CorruptScan, words)
        assert "root:" not in msg


def test_the_passwd_file_never_comes_back_as_heights(tmp_path):
    """The issue's measurement: a 2 kB .topostats whose image is external storage on /etc/passwd."""
    p, _ = _topostats(tmp_path / "x.topostats")
    plant(p, "image", "external_storage", tmp_path)
    assert os.path.getsize(p) < 4096
    with pytest.raises(CorruptScan, match=r"/image uses HDF5 external storage .*'/etc/passwd'"):
        load_scan(p)


def test_a_fifo_as_the_scan_file_is_refused_without_blocking(tmp_path):
    fifo = make_fifo(tmp_path)
    link = tmp_path / "scan.topostats"
    os.symlink(fifo, link)
    with FifoGuard(fifo):
        for p in (fifo, link):
            _refused(lambda: load_scan(p), ScanError, "")
    with FifoGuard(fifo):
        _refused(lambda: open_hdf5(fifo, "scan file"), UnsafeFile, "FIFO")


def test_declared_size_budget_is_sixteen_times_the_file(tmp_path):
    """A dataset may declare up to 16x the file's bytes (gzip data), not one byte more."""
    p = tmp_path / "z.h5"
    with h5py.File(p, "w") as f:
        f.create_dataset("a", data=np.zeros(400_000), compression="gzip", chunks=(50_000,))
    size = os.path.getsize(p)
    assert 400_000 * 8 > MAX_EXPANSION * size  # zeros compress ~1000x: over the budget
    with pytest.raises(UnsafeFile, match="declares 3200000 bytes"):
        open_hdf5(p, "file")
    with h5py.File(p, "w") as f:
        f.create_dataset("a", data=np.random.default_rng(0).normal(size=4000))
    with open_hdf5(p, "file") as f:
        assert f["a"].shape == (4000,)


def test_soft_links_inside_the_tree_are_kept(tmp_path):
    p = tmp_path / "s.topostats"
    _topostats(p)
    with h5py.File(p, "a") as f:
        f.move("image", "data/image")
        f["image"] = h5py.SoftLink("/data/image")
    assert load_scan(p).heights.shape == (8, 8)
    with open_hdf5(p, "file", tree="/data") as f:
        assert f["image"].shape == (8, 8)
    with pytest.raises(UnsafeFile, match="soft link"):
        open_hdf5(p, "file", soft_links=False)


# ---------------------------------------------------------------------------------------------
# sessions and replay outputs: the seal says the bytes are intact, not that they are harmless


def _session(tmp_path, n=40):
    from arsurf.sessions.writer import SessionWriter
    from test_session_fuzz import _meta, _record

    p = tmp_path / "s.h5"
    with SessionWriter(p, _meta(), created="2026-01-01T00:00:00+00:00") as w:
        _record(w, n, np.random.default_rng(1))
    return p


@pytest.mark.parametrize("isolate", [False, "auto", True])
@pytest.mark.parametrize("kind", sorted(KINDS))
def test_a_resealed_session_is_checked_by_the_same_rules(tmp_path, kind, isolate):
    """The issue's attack: probe_position re-pointed outside the file, checksums and seal redone.
    Refused in this process (sealed: isolate False / "auto"), and by the isolated
    reader (True) with the same one line."""
    from arsurf.sessions.reader import load_session

    p = _session(tmp_path)
    assert load_session(p).verified
    words = plant(p, "ticks/probe_position", kind, tmp_path)
    reseal_session(p)
    with FifoGuard(make_fifo(tmp_path)):
        if isolate is True:
            with pytest.raises(SessionError, match=words):
                load_session(p, isolate=True)
        else:
            _refused(lambda: load_session(p, isolate=isolate), SessionError, words)


@pytest.mark.parametrize("kind", ["external_storage", "external_link", "virtual_dataset"])
def test_an_unsealed_session_is_refused_in_process_too(tmp_path, kind):
    from arsurf.sessions.reader import load_session

    p = _session(tmp_path)
    data = p.read_bytes()
    p.write_bytes(b"\0" * 512 + data[512:])  # the seal wiped: a plain HDF5 file with a user block
    raw = tmp_path / "raw.h5"
    with h5py.File(p, "r") as src, h5py.File(raw, "w") as dst:
        for k, v in src.attrs.items():
            dst.attrs[k] = v
        src.copy("metadata", dst)
        src.copy("ticks", dst)
    plant(raw, "ticks/probe_position", kind, tmp_path)
    _refused(lambda: load_session(raw, isolate=False), SessionError, KINDS[kind])


def test_a_fifo_session_is_refused_without_blocking(tmp_path):
    from arsurf.sessions.reader import load_session

    fifo = make_fifo(tmp_path)
    for isolate in ("auto", False, True):
        with FifoGuard(fifo):
            _refused(lambda: load_session(fifo, isolate=isolate), SessionError, "FIFO")


def test_a_replay_output_is_read_by_the_same_rules(tmp_path):
    from arsurf.sessions.reader import read_h5
    from arsurf.sessions.schema import TickField
    from arsurf.sessions.writer import write_h5

    p = tmp_path / "r.h5"
    fields = (TickField("t", 0, "f8", float("nan"), "", "s"),)
    write_h5(p, {"format": "x-test", "format_version": np.int64(1), "complete": np.bool_(True), "n_ticks": np.int64(4)},
             {}, {"t": np.arange(4.0)}, {"t": "s"})
    assert read_h5(p, fmt="x-test", versions=(1,), fields=fields, isolate=False).ticks["t"].tolist() == [0, 1, 2, 3]
    plant(p, "ticks/t", "external_storage", tmp_path)
    reseal_session(p)
    _refused(lambda: read_h5(p, fmt="x-test", versions=(1,), fields=fields, isolate=False), SessionError,
             "external storage")
