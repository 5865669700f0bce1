"""Batch state is verified, not trusted: each row records its output files' size and SHA-256 and a
resumed batch re-checks them; each item has a time limit; ``batch replay`` without ``--scan`` reads
the session through the checked reader and never opens a file outside the batch's inputs."""
from __future__ import annotations

import csv
import dataclasses
import hashlib
import os
import shutil
import time

import pytest

from arsurf import batch
from arsurf.batch import PIPELINES, read_results, run_batch
from arsurf.errors import BatchError
from arsurf.scan.io import save_scan
from hdf5_attacks import make_fifo, plant, reseal_session, set_recorded_scan
from test_batch import _scan, _session, folder  # noqa: F401 - the fixture


def _rewrite(out, edit):
    """Rewrite results.csv with ``edit(row)`` applied to every row (a user, or a forger)."""
    path = out / "results.csv"
    with open(path, newline="") as fh:
        lines = list(csv.reader(fh))
    header = lines[0]
    rows = [dict(zip(header, r)) for r in lines[1:]]
    for r in rows:
        edit(r)
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(header)
        w.writerows([[r[c] for c in header] for r in rows])


def test_each_row_records_its_outputs_size_and_sha256(folder, tmp_path):
    out = tmp_path / "out"
    run_batch("process", [folder], out, workers=0, progress=False, options={"export": [".stl"]})
    row = read_results(out)["s0.gsf"]
    entries = [e.split("|") for e in row["output_files"].split(";")]
    assert sorted(rel for rel, _, _ in entries) == ["s0.gsf.stl", "s0.gsf.surface.npz"]
    for rel, size, digest in entries:
        data = (out / rel).read_bytes()
        assert int(size) == len(data) and digest == hashlib.sha256(data).hexdigest()


TAMPER = {
    "output deleted": lambda out, r: (out / "s1.npz.surface.npz").unlink(),
    "output changed": lambda out, r: (out / "s1.npz.surface.npz").write_bytes(b"not the fitted surface"),
    "row forged, no output listed": lambda out, r: _rewrite(out, lambda row: row.update(
        output_files="") if row["item"] == "s1.npz" else None),
    "row forged, values do not parse": lambda out, r: _rewrite(out, lambda row: row.update(
        item_time_s="fast") if row["item"] == "s1.npz" else None),
    "row forged, hash of another file": lambda out, r: _rewrite(out, lambda row: row.update(
        output_files=row["output_files"].replace(row["output_files"].split("|")[2][:64], "0" * 64))
        if row["item"] == "s1.npz" else None),
}


@pytest.mark.parametrize("case", sorted(TAMPER))
def test_resume_reruns_an_item_whose_row_or_outputs_do_not_check(folder, tmp_path, case):
    out = tmp_path / "out"
    (folder / "broken.gsf").unlink()
    run_batch("process", [folder], out, workers=0, progress=False)
    TAMPER[case](out, None)
    r = run_batch("process", [folder], out, workers=0, progress=False, resume=True)
    assert (r.skipped, r.ran, r.ok) == (2, 1, 3)
    rows = read_results(out)
    assert rows["s1.npz"]["status"] == "ok" and batch._row_stands(rows["s1.npz"], PIPELINES["process"].columns, out)
    r = run_batch("process", [folder], out, workers=0, progress=False, resume=True)
    assert (r.skipped, r.ran) == (3, 0)  # now everything checks


def test_an_item_past_its_time_limit_is_an_error_row_and_the_batch_goes_on(folder, tmp_path, monkeypatch):
    (folder / "broken.gsf").unlink()
    real = PIPELINES["process"]

    def slow_on_s1(item, o, out_dir):
        if item.key == "s1.npz":
            time.sleep(60)  # stands for an item that never finishes
        return real.task(item, o, out_dir)

    monkeypatch.setitem(batch.PIPELINES, "process", dataclasses.replace(real, task=slow_on_s1))
    t0 = time.perf_counter()
    r = run_batch("process", [folder], tmp_path / "out", workers=0, progress=False, item_timeout=0.5)
    assert time.perf_counter() - t0 < 30
    assert (r.ok, r.failed) == (2, 1)
    assert dict(r.errors)["s1.npz"].startswith("ItemTimeout: the item ran longer than its time limit (0.5 s)")
    with pytest.raises(BatchError, match="item_timeout must be a positive number"):
        run_batch("process", [folder], tmp_path / "o2", workers=0, progress=False, item_timeout=-1)


def test_batch_replay_never_opens_a_scan_outside_its_inputs(tmp_path, monkeypatch):
    """A session naming a file outside the batch's inputs (a FIFO, which would block whoever opens
    it; /etc/passwd) is an error row; the file is not opened or hashed."""
    d = tmp_path / "sessions"
    d.mkdir()
    save_scan(_scan(0), d / "scan.npz")
    fifo = make_fifo(tmp_path)
    monkeypatch.chdir(d)
    _session(tmp_path / "model.h5", "scan.npz", 6e-9)
    monkeypatch.chdir(tmp_path)
    for name, scan in (("fifo.h5", str(fifo)), ("passwd.h5", "/etc/passwd"), ("up.h5", "../pipe")):
        shutil.copy(tmp_path / "model.h5", d / name)
        set_recorded_scan(d / name, scan)
    r = run_batch("replay", [d], tmp_path / "out", workers=0, progress=False, item_timeout=120)
    errors = dict(r.errors)
    assert r.ok == 0 and sorted(errors) == ["fifo.h5", "passwd.h5", "up.h5"]
    for key in errors:
        assert "outside the batch's inputs" in errors[key] and "not opened" in errors[key]


def test_batch_replay_reads_the_session_through_the_checked_reader(tmp_path, monkeypatch):
    d = tmp_path / "sessions"
    d.mkdir()
    save_scan(_scan(0), d / "scan.npz")
    monkeypatch.chdir(d)
    _session(d / "a.h5", "scan.npz", 6e-9)
    monkeypatch.chdir(tmp_path)
    plant(d / "a.h5", "ticks/probe_position", "external_storage", tmp_path)
    reseal_session(d / "a.h5")
    r = run_batch("replay", [d], tmp_path / "out", workers=0, progress=False)
    assert r.failed == 1 and "external storage" in dict(r.errors)["a.h5"]


def test_a_batch_of_the_previous_format_is_not_resumed_unverified(folder, tmp_path):
    import json

    out = tmp_path / "out"
    run_batch("process", [folder], out, workers=0, progress=False)
    settings = json.loads((out / "batch.json").read_text())
    (out / "batch.json").write_text(json.dumps({**settings, "version": 2}))
    with pytest.raises(BatchError, match="cannot be verified, so not resumed"):
        run_batch("process", [folder], out, workers=0, progress=False, resume=True)
