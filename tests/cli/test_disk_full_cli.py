"""A disk that fills up while the command line records is said at once, on stderr, not only at the
end: ``arsurf live --record``, ``arsurf view --record`` and ``arsurf demo`` each print one warning
line within a second of the failed write (the writer thread's error, flagged at the next append),
then end with a one-line error counting the ticks not recorded, exit 2, and keep the journal's
ticks for ``recover_session``. The full disk is ENOSPC from ``os.write`` on the journal's file
descriptor (the only writes of a recording), injected in the same process."""
from __future__ import annotations

import errno
import logging
import os
import signal
import socket
import subprocess
import sys
import threading
import time

import pytest

from arsurf.cli import main
from arsurf.haptics.udp_bridge import generate_key, save_key
from arsurf.sessions.journal import JOURNAL_SUFFIX
from arsurf.sessions.reader import load_session
from tests.support.waiting import udp_port_bound

# a warning within a second of the failed write: alone under xdist (docs/testing.rst)
pytestmark = pytest.mark.realtime

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")


class FullDisk:
    """``os.write`` or ``os.writev`` on a ``*.journal`` descriptor fails with ENOSPC from its ``after``-th call on
    (the first is the journal's header, then one per chunk of ticks, at least every 50 ms); the
    wall time of the first failure is kept."""

    def __init__(self, monkeypatch, after: int):
        self.after, self.calls, self.failed_at = after, 0, None
        for name in ("write", "writev"):
            monkeypatch.setattr(os, name, self._failing(getattr(os, name)))

    def _failing(self, real):
        def write(fd, data):
            if os.readlink(f"/proc/self/fd/{fd}").endswith(JOURNAL_SUFFIX):
                self.calls += 1
                if self.calls > self.after:
                    self.failed_at = time.monotonic() if self.failed_at is None else self.failed_at
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            return real(fd, data)

        return write


class Heard(logging.Handler):
    """The wall time and text of the writer's warnings."""

    def __init__(self):
        super().__init__(logging.WARNING)
        self.records = []

    def emit(self, record):
        self.records.append((time.monotonic(), record.getMessage()))


@pytest.fixture
def heard():
    h = Heard()
    log = logging.getLogger("arsurf.sessions.writer")
    log.addHandler(h)
    yield h
    log.removeHandler(h)


def _reported(disk, heard, err, path):
    """The checks common to every command: one warning within 1 s, one final error with the count."""
    assert disk.failed_at is not None, "the journal was never written"
    warnings = [(t, m) for t, m in heard.records if "No space left on device" in m]
    assert len(warnings) == 1, heard.records
    t, message = warnings[0]
    assert 0.0 <= t - disk.failed_at < 1.0, f"reported {t - disk.failed_at:.3f} s after the failed write"
    assert "\n" not in message and "nothing more is recorded" in message
    lines = [line for line in err.splitlines() if "No space left on device" in line]
    assert len(lines) == 2, err  # the warning as it happened, the error at the end
    assert "nothing more is recorded" in lines[0]
    assert "error: recording to" in lines[1] and "were not recorded" in lines[1]
    unrecorded = int(lines[1].split("the ")[-1].split(" appended")[0])
    kept = load_session(path, allow_incomplete=True)  # read from the journal the writer kept
    assert unrecorded > 0 and kept.n_ticks > 0 and not kept.complete
    device = kept.metadata["device"]  # the limits the reader bounds the stylus and the device force by
    assert len(device["workspace"]) == 3 and min(device["workspace"]) > 0 and device["max_force"] > 0
    return kept, unrecorded


def test_arsurf_live_record_says_a_full_disk_within_a_second(monkeypatch, capsys, heard, tmp_path):
    path = tmp_path / "s.h5"
    # the loop's kernels loaded first (what arsurf.warmup does at install): a cold cache compiles
    # them inside the first session, and a loop stalled compiling appends nothing to flag with
    assert main(["live", "--device", "virtual", "--seconds", "0.2"]) == 0
    capsys.readouterr()
    disk = FullDisk(monkeypatch, after=12)  # ~0.6 s into the recording, past its start
    rc = main(["live", "--device", "virtual", "--seconds", "2", "--record", str(path)])
    err = capsys.readouterr().err
    assert rc == 2 and not path.exists()
    kept, unrecorded = _reported(disk, heard, err, path)
    assert kept.n_ticks + unrecorded > 300  # the loop kept appending to the end (1.5 s at up to 1 kHz)


def test_arsurf_demo_says_a_full_disk_within_a_second(monkeypatch, capsys, heard, tmp_path):
    out = tmp_path / "demo"
    disk = FullDisk(monkeypatch, after=2)
    rc = main(["demo", "--out", str(out), "--seconds", "2", "--no-images"])
    err = capsys.readouterr().err
    assert rc == 2 and not (out / "session.h5").exists()
    kept, unrecorded = _reported(disk, heard, err, out / "session.h5")
    assert kept.n_ticks + unrecorded == 2000


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_arsurf_view_record_says_a_full_disk_within_a_second(monkeypatch, capsys, heard, tmp_path):
    """The reference client drives the bridge for 2 s, then says RELEASE; the view ends with it."""
    path, kf = tmp_path / "v.h5", save_key(tmp_path / "bridge.key", generate_key())
    port = _free_port()
    disk = FullDisk(monkeypatch, after=12)  # ~0.6 s into the recording, past its start
    client, done = [], threading.Event()

    def drive():
        deadline = time.monotonic() + 900.0  # a cold start compiles the model's kernels: minutes on a busy machine
        # the view builds its model, then binds the port: asked of the kernel's table, never by binding
        # it (a probe holding the port at the instant the view binds made the view fail, once in a run)
        while time.monotonic() < deadline and not udp_port_bound(port):
            if done.wait(0.05):
                return  # the view ended without listening: its error is asserted below
        client.append(subprocess.run([sys.executable, "-m", "arsurf.haptics.client", "--port", str(port),
                                      "--key-file", str(kf), "--duration", "2", "--radius", "0.01"],
                                     capture_output=True, text=True, timeout=120, cwd=ROOT))
        if not done.wait(30.0):  # the view missed the RELEASE: stop it as Ctrl-C would, never hang
            os.kill(os.getpid(), signal.SIGINT)

    th = threading.Thread(target=drive, daemon=True)
    th.start()
    try:
        rc = main(["view", "--bridge-port", str(port), "--bridge-key-file", str(kf), "--record", str(path),
                   "--frames", "0", "--realtime-priority", "10"])
    finally:
        done.set()
    th.join(200)
    err = capsys.readouterr().err
    assert client and client[0].returncode == 0, client[0].stderr if client else f"no client ran: view rc {rc}, {err}"
    assert rc == 2 and not path.exists()
    _reported(disk, heard, err, path)
    if os.geteuid() == 0:  # the loop thread got the real-time policy the bridge needs under a flood
        assert "(SCHED_FIFO priority 10)" in err, err
