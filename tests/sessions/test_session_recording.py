"""Recording survives the process dying: a real recorder is killed (SIGKILL) or stopped
(SIGTERM, SIGINT) while it writes at ~1 kHz, and the session is read back; the journal is cut
at every byte; a stalled disk drops ticks instead of blocking; memory stays flat."""
from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import textwrap
import threading
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from arsurf.assembly import session_metadata
from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.errors import SessionError
from arsurf.force.cantilever import Cantilever
from arsurf.sessions import journal as journal_mod
from arsurf.sessions.journal import journal_path
from arsurf.sessions.reader import load_session
from arsurf.sessions.recover import recover_session
from arsurf.sessions.writer import SessionWriter

ROOT = Path(__file__).resolve().parents[2]
R = 20e-9
SCAN = {"path": "scans/sinusoid.npz", "sha256": "ab" * 32, "channel": None,
        "processing": {"level": "plane", "sigma": 2e-9, "inpaint": True}}


def meta():
    return session_metadata(scan=SCAN, tip_radius=R, contact=MaugisDugdale(R, 50e9, 0.1),
                            cantilever=Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27), loop_rate=1000.0)


def position(k):
    """The known probe position of tick k (exact in float64)."""
    return (k * 1e-9, -k * 1e-9, 0.5 * k * 1e-9)


#: the recorder child: appends tick k at ~1 kHz with t = its CLOCK_MONOTONIC time and a known
#: position, and logs "k t" after each append (line-buffered file, so a kill loses no line)
RECORDER = textwrap.dedent("""
    import json, sys, time
    from arsurf.sessions.writer import SessionWriter
    path, log, meta, handle = sys.argv[1], sys.argv[2], json.loads(sys.argv[3]), sys.argv[4] == "1"
    out = open(log, "w", buffering=1)
    w = SessionWriter(path, meta, handle_signals=handle)
    k = 0
    try:
        with w:
            out.write("ready\\n")
            nxt = time.monotonic()
            while True:
                t = time.monotonic()
                w.append(t=t, probe_position=(k * 1e-9, -k * 1e-9, 0.5 * k * 1e-9), buttons=k % 7)
                out.write(f"{k} {t!r}\\n")
                k += 1
                nxt += 1e-3
                time.sleep(max(0.0, nxt - time.monotonic()))
    except KeyboardInterrupt:
        out.write(f"final {w.n_ticks}\\n")
""")


def _start(tmp_path, handle=False):
    path = tmp_path / "run.h5"
    log = tmp_path / "log.txt"
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.Popen([sys.executable, "-c", RECORDER, str(path), str(log), json.dumps(meta()),
                             "1" if handle else "0"], env=env, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 60
    while not (log.exists() and log.read_text().startswith("ready")):
        assert proc.poll() is None, proc.stderr.read().decode()
        assert time.monotonic() < deadline, "the recorder did not start"
        time.sleep(0.01)
    return proc, path, log


def _logged(log):
    ticks, final = {}, None
    for line in log.read_text().splitlines()[1:]:
        parts = line.split()
        if parts[0] == "final":
            final = int(parts[1])
        elif len(parts) == 2:
            ticks[int(parts[0])] = float(parts[1])
    return ticks, final


def _check_prefix(s, logged):
    """The ticks read are ticks 0..n-1, exactly as appended."""
    n = s.n_ticks
    k = np.arange(n)
    np.testing.assert_array_equal(s.ticks["probe_position"], np.array([position(i) for i in k]).reshape(n, 3))
    np.testing.assert_array_equal(s.ticks["buttons"], k % 7)
    assert np.isnan(s.ticks["force"]).all()
    have = [i for i in range(n) if i in logged]
    np.testing.assert_array_equal(s.ticks["t"][have], [logged[i] for i in have])


@pytest.mark.realtime
@pytest.mark.parametrize("trial", range(4))
def test_sigkill_at_a_random_moment_keeps_every_tick_older_than_100_ms(tmp_path, trial):
    rng = random.Random(1000 + trial)
    proc, path, log = _start(tmp_path)
    time.sleep(rng.uniform(0.15, 0.9))
    killed_at = time.monotonic()
    proc.kill()
    proc.wait()
    logged, _ = _logged(log)
    assert not path.exists() and journal_path(path).exists()
    with pytest.raises(SessionError, match=r"incomplete .*interrupted.* ticks recovered.*allow_incomplete=True"):
        load_session(path)
    s = load_session(path, allow_incomplete=True)
    assert s.recovered and not s.complete and s.attrs["format_version"] == 2
    old = [k for k, t in logged.items() if t < killed_at - 0.100]
    assert len(old) > 50  # the recorder ran a while
    assert s.n_ticks >= max(old) + 1, (s.n_ticks, max(old), len(logged))
    assert s.n_ticks <= max(logged) + 2  # nothing invented (at most one appended and not yet logged)
    _check_prefix(s, logged)
    # and it becomes an ordinary (incomplete) session file
    out = recover_session(path)
    assert out == path and not journal_path(path).exists()
    again = load_session(path, allow_incomplete=True)
    assert again.verified and not again.recovered and again.n_ticks == s.n_ticks
    assert "interrupted" in again.attrs["aborted"]
    for name in s.ticks:
        assert s.ticks[name].tobytes() == again.ticks[name].tobytes(), name


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_sigterm_and_sigint_close_the_file_with_every_tick(tmp_path, sig):
    proc, path, log = _start(tmp_path, handle=True)
    time.sleep(0.4)
    proc.send_signal(sig)
    assert proc.wait(timeout=60) == 0, proc.stderr.read().decode()
    logged, final = _logged(log)
    assert final is not None and final >= max(logged) + 1 >= 200
    assert not journal_path(path).exists()
    with pytest.raises(SessionError, match=rf"incomplete .*stopped by {sig.name}"):
        load_session(path)
    s = load_session(path, allow_incomplete=True)
    assert s.n_ticks == final and s.verified and s.attrs["aborted"] == f"stopped by {sig.name}"
    _check_prefix(s, logged)


def test_signal_handlers_are_restored_at_close(tmp_path):
    before = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)
    with SessionWriter(tmp_path / "s.h5", meta(), handle_signals=True) as w:
        assert signal.getsignal(signal.SIGTERM) == w._on_signal
        w.append(t=0.0, probe_position=(0, 0, 0))
    assert (signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)) == before


def test_a_signal_while_a_servo_thread_appends_interrupts_the_main_thread(tmp_path):
    """A live loop appends from its servo thread: SIGINT arriving while that thread is inside
    append interrupts the main thread at once (which then stops the loop and closes the file);
    the servo thread's append finishes normally, never raising the interruption in the loop."""
    from arsurf.errors import RecordingInterrupted

    errors, interrupted = [], []
    w = SessionWriter(tmp_path / "s.h5", meta(), handle_signals=True)
    with pytest.raises(RecordingInterrupted):
        with w:
            w.append(t=0.0, probe_position=position(0))

            def servo():
                try:
                    w.append(t=1e-3, probe_position=position(1))
                except BaseException as exc:  # noqa: BLE001 - what the servo thread would see
                    errors.append(exc)

            w._stream.lock.acquire()  # the servo thread blocks inside append
            th = threading.Thread(target=servo)
            th.start()
            time.sleep(0.2)
            try:
                signal.raise_signal(signal.SIGINT)
            except RecordingInterrupted as exc:
                interrupted.append(exc)
            finally:
                w._stream.lock.release()
                th.join(10)  # the loop is stopped before the file closes, as arsurf view does
            raise interrupted[0] if interrupted else AssertionError("SIGINT did not interrupt the main thread")
    assert interrupted and "stopped by SIGINT" in str(interrupted[0])
    assert not th.is_alive() and errors == []
    s = load_session(tmp_path / "s.h5", allow_incomplete=True)
    assert s.n_ticks == 2 and s.attrs["aborted"] == "stopped by SIGINT"


def _killed_journal(tmp_path, n=300, capacity=16):
    """A journal as a killed recorder leaves it: records written, no end record."""
    path = tmp_path / "k.h5"
    w = SessionWriter(path, meta(), capacity=capacity, when_full="wait")
    for k in range(n):
        w.append(t=k * 1e-3, probe_position=position(k), buttons=k % 7)
    w._stream.stop()  # what was appended reaches the journal; then "the process dies"
    w._file.close()
    w._closed = True
    return path, journal_path(path)


def test_a_journal_cut_at_any_byte_gives_back_its_complete_records(tmp_path):
    path, jp = _killed_journal(tmp_path)
    data = jp.read_bytes()
    index = journal_mod.scan_journal(jp)
    assert index.n_ticks == 300 and index.discarded_bytes == 0 and index.end is None
    ends = [off + length + 32 for off, length, _, _ in index.records]  # byte where each record ends
    cut = tmp_path / "cut.h5.journal"
    for at in sorted(set(range(0, len(data), 331)) | {e - 1 for e in ends} | set(ends)):
        cut.write_bytes(data[:at])
        complete = sum(1 for e in ends if e <= at)
        if at < index.records[0][0] - 40:  # the header record itself is cut
            with pytest.raises(SessionError, match="no intact header"):
                load_session(cut, allow_incomplete=True)
            continue
        s = load_session(cut, allow_incomplete=True)
        assert s.n_ticks == 16 * complete if complete < len(ends) else 300, at
        np.testing.assert_array_equal(s.ticks["probe_position"],
                                      np.array([position(k) for k in range(s.n_ticks)]).reshape(-1, 3))


def test_a_damaged_record_ends_the_recovery_there(tmp_path, rng):
    path, jp = _killed_journal(tmp_path)
    data = bytearray(jp.read_bytes())
    index = journal_mod.scan_journal(jp)
    off, length, first, n = index.records[5]
    for _ in range(20):
        bad = bytearray(data)
        i = int(rng.integers(off - 40, off + length + 32))
        bad[i] ^= 1 << int(rng.integers(8))
        jp.write_bytes(bytes(bad))
        s = load_session(path, allow_incomplete=True)
        assert s.n_ticks == first  # records 0..4, exactly
        np.testing.assert_array_equal(s.ticks["probe_position"], [position(k) for k in range(first)])
        assert "byte" in s.attrs["aborted"]


def test_a_stalled_disk_drops_ticks_and_never_blocks_append(tmp_path, monkeypatch):
    import threading

    gate = threading.Event()
    real = journal_mod.JournalFile.write

    def slow(self, kind, parts):
        if kind == journal_mod.TICKS:
            gate.wait()
        real(self, kind, parts)

    monkeypatch.setattr(journal_mod.JournalFile, "write", slow)
    w = SessionWriter(tmp_path / "s.h5", meta(), capacity=8, queue_chunks=2)
    for k in range(200):  # the writer thread is stuck: the pool (2 + 1 chunks) fills, then chunks drop
        w.append(t=k * 1e-3, probe_position=position(k))
    assert w.dropped_ticks > 0 and w.n_ticks + w.dropped_ticks == 200
    gate.set()
    w.close()
    s = load_session(tmp_path / "s.h5")
    assert s.attrs["dropped_ticks"] == w.dropped_ticks and s.n_ticks == w.n_ticks
    kept = np.round(s.ticks["t"] / 1e-3).astype(int)
    assert np.all(np.diff(kept) > 0)  # kept ticks in order; a gap where chunks were dropped
    np.testing.assert_array_equal(s.ticks["probe_position"], [position(k) for k in kept])


def test_a_journal_record_is_written_without_copying_its_ticks(tmp_path):
    """The writer thread hands the chunk's own arrays to the disk: a 1 MB record allocates no 1 MB copy
    (so nothing transient the size of a chunk is in memory while it is written; CI saw 173 kB of it)."""
    file = journal_mod.JournalFile(tmp_path / "j", {"what": "test"}, fsync=False)
    block = np.arange(131072, dtype=np.float64)  # 1 MiB
    tracemalloc.start()
    file.write(journal_mod.TICKS, [b"head", block[:100000]])
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    file.close()
    assert peak < 50_000, peak
    raw = (tmp_path / "j").read_bytes()
    assert block[:100000].tobytes() in raw  # and the bytes on disk are the block's


@pytest.mark.parametrize("call", ["write", "writev"])
def test_short_writes_still_put_the_whole_record_on_disk(tmp_path, monkeypatch, call):
    """The system may write fewer bytes than asked (a signal, a pipe, a full quota): the rest follows."""
    real = getattr(os, call)
    short = (lambda fd, data: real(fd, data[:7])) if call == "write" else (lambda fd, bufs: real(fd, [bufs[0][:7]]))
    monkeypatch.setattr(os, call, short)
    if call == "write":
        monkeypatch.delattr(os, "writev", raising=False)
        monkeypatch.setattr(journal_mod, "_WRITEV", False)
    block = np.arange(1000, dtype=np.float64)
    file = journal_mod.JournalFile(tmp_path / "j", {"what": "test"}, fsync=False)
    file.write(journal_mod.TICKS, [b"head", block])
    file.close()
    monkeypatch.undo()
    expected = b"".join(bytes(b) for b in journal_mod._record(journal_mod.TICKS, [b"head", block]))
    assert (tmp_path / "j").read_bytes().endswith(expected)


def test_memory_stays_flat_however_long_the_recording(tmp_path):
    w = SessionWriter(tmp_path / "s.h5", meta(), when_full="wait")
    fields = dict(probe_velocity=(1e-6, 0.0, 0.0), force=(0.0, 0.0, 1e-9), depth=1e-9, md_status=0)
    k = 0

    def run(n):
        nonlocal k
        for _ in range(n):
            w.append(t=k * 1e-3, probe_position=position(k), **fields)
            k += 1

    run(5000)  # warm: the pool and the writer thread exist
    tracemalloc.start()
    # the recorder's own allocations (threads left by other tests allocate in this process too)
    mine = [tracemalloc.Filter(True, "*arsurf/sessions/*"), tracemalloc.Filter(True, "*h5py*")]

    def traced() -> int:
        return sum(st.size for st in tracemalloc.take_snapshot().filter_traces(mine).statistics("filename"))

    run(5000)
    first = traced()
    run(40000)
    last = traced()
    tracemalloc.stop()
    # 40 000 more ticks (15 MB of data) and the traced memory has not grown by 0.1 MB
    assert last - first < 100_000, (first, last)
    w.close()
    assert load_session(tmp_path / "s.h5").n_ticks == 50000


def test_a_stale_journal_is_never_overwritten(tmp_path):
    path, jp = _killed_journal(tmp_path, n=20)
    before = jp.read_bytes()
    with pytest.raises(SessionError, match="unfinished recording exists; recover it"):
        SessionWriter(path, meta())
    assert jp.read_bytes() == before
    recover_session(jp)
    with SessionWriter(path, meta()) as w:
        w.append(t=0.0, probe_position=(0, 0, 0))
    assert load_session(path).n_ticks == 1


def test_arsurf_replay_says_a_killed_recording_is_incomplete_and_replays_what_was_recovered(tmp_path, capsys):
    from arsurf.cli import main
    from arsurf.scan import synthetic
    from arsurf.scan.io import save_scan

    scan = save_scan(synthetic.sinusoid(shape=(16, 16), pixel=10e-9, amplitude=2e-9, period=80e-9), tmp_path / "s.npz")
    m = session_metadata(scan=scan, tip_radius=R, contact=MaugisDugdale(R, 50e9, 0.1), level="plane", sigma=0.0,
                         inpaint=True, cantilever=Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27))
    path = tmp_path / "run.h5"
    w = SessionWriter(path, m, capacity=8, when_full="wait")
    for k in range(50):
        w.append(t=k * 1e-3, probe_position=(60e-9 + k * 1e-9, 70e-9, 40e-9), probe_velocity=(1e-6, 0.0, 0.0))
    w._stream.stop()  # killed: the journal holds the 50 ticks, no end record
    w._file.close()
    w._closed = True
    assert main(["replay", str(path), "--scan", str(scan), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "incomplete" in err and "50 ticks recovered" in err and "--allow-incomplete" in err
    assert main(["replay", str(path), "--scan", str(scan), "--out", str(tmp_path / "out"), "--allow-incomplete"]) == 0
    captured = capsys.readouterr()
    assert "is incomplete" in captured.err and "replaying the 50 ticks" in captured.err
    assert "replayed 50 ticks" in captured.out
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["n_ticks"] == 50 and "interrupted" in summary["session_incomplete"]
    assert summary["session_recovered_from_journal"] is True


def test_a_writer_dropped_without_close_leaves_its_ticks_in_the_journal(tmp_path):
    import gc
    import threading

    before = set(threading.enumerate())  # other tests' threads may end meanwhile: look at the new ones only
    w = SessionWriter(tmp_path / "s.h5", meta())
    for k in range(10):
        w.append(t=k * 1e-3, probe_position=position(k))
    assert set(threading.enumerate()) - before  # the writer thread runs
    del w
    gc.collect()
    assert not (set(threading.enumerate()) - before)  # its writer thread stopped
    s = load_session(tmp_path / "s.h5", allow_incomplete=True)
    assert s.recovered and s.n_ticks == 10
