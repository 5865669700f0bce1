"""A session makes sense before it is replayed, and a recording that cannot reach the disk says so
at once: ticks whose time goes back, positions no device or scanner can reach, forces no device
can give are refused naming the tick and the field; a full disk is flagged at the next append;
a planted link where the session goes is never written through."""
from __future__ import annotations

import errno
import logging
import os

import numpy as np
import pytest

from arsurf.errors import SessionError
from arsurf.sessions import journal as _journal
from arsurf.sessions.reader import DEVICE_FORCE_LIMIT, load_session
from arsurf.sessions.writer import _OPEN_WRITERS, SessionWriter
from test_session_fuzz import _meta

N = 30


def _write(path, edit=None, meta=None, n=N):
    """A session of n plausible ticks, tick values changed by ``edit(k, fields)`` first."""
    rng = np.random.default_rng(3)
    with SessionWriter(path, meta or _meta(), created="2026-01-01T00:00:00+00:00") as w:
        for k in range(n):
            f = {"t": k * 1e-3, "probe_position": rng.normal(size=3) * 1e-7,
                 "stylus_position": rng.normal(size=3) * 1e-2, "device_force": rng.normal(size=3),
                 "force": rng.normal(size=3) * 1e-9}
            if edit is not None:
                edit(k, f)
            w.append(**f)
    return path


def test_plausible_ticks_load(tmp_path):
    s = load_session(_write(tmp_path / "ok.h5"))
    assert s.n_ticks == N and s.verified


BAD = {
    "time goes back": (lambda k, f: f.update(t=0.0) if k == 7 else None, r"tick 7: t = 0\.0 s is not after tick 6"),
    "time stands still": (lambda k, f: f.update(t=5e-3) if k == 6 else None, r"tick 6: t = 0\.005 s is not after"),
    "time not finite": (lambda k, f: f.update(t=float("nan")) if k == 4 else None, r"tick 4: t = nan s is not finite"),
    "stylus 1 km away": (lambda k, f: f.update(stylus_position=[1e3, 0, 0]) if k == 11 else None,
                         r"tick 11: stylus_position = \[1000\.0, 0\.0, 0\.0\] m .*reaches farther"),
    "probe 1 m away": (lambda k, f: f.update(probe_position=[0, 1.0, 0]) if k == 3 else None,
                       r"tick 3: probe_position = .*scanner's travel"),
    "infinite probe": (lambda k, f: f.update(probe_position=[0, np.inf, 0]) if k == 2 else None,
                       r"tick 2: probe_position = \[0\.0, inf, 0\.0\] m is infinite"),
    "device force 1.9e8 N": (lambda k, f: f.update(device_force=[1.9e8, 0, 0]) if k == 9 else None,
                             r"tick 9: device_force = \[190000000\.0, 0\.0, 0\.0\] N .*pushes harder"),
    "infinite tip force": (lambda k, f: f.update(force=[np.inf, 0, 0]) if k == 1 else None, r"tick 1: force = .*infinite"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_ticks_that_cannot_be_real_are_refused_naming_tick_and_field(tmp_path, case):
    edit, match = BAD[case]
    p = _write(tmp_path / "bad.h5", edit)
    for isolate in (False, True):
        with pytest.raises(SessionError, match=match) as info:
            load_session(p, isolate=isolate)
        assert "\n" not in str(info.value)


def test_the_recorded_device_limits_are_used_when_given(tmp_path):
    meta = _meta()
    meta["haptics"] = {"device": "virtual", "max_force": 3.3, "workspace": [0.12, 0.16, 0.12]}
    load_session(_write(tmp_path / "ok.h5", meta=meta, edit=lambda k, f: f.update(device_force=[3.3, 0, 0])))
    with pytest.raises(SessionError, match=r"tick 5: device_force .*recorded device's max_force"):
        load_session(_write(tmp_path / "f.h5", meta=meta,
                            edit=lambda k, f: f.update(device_force=[4.0, 0, 0]) if k == 5 else None))
    with pytest.raises(SessionError, match=r"tick 8: stylus_position .*recorded device workspace"):
        load_session(_write(tmp_path / "w.h5", meta=meta,
                            edit=lambda k, f: f.update(stylus_position=[0.5, 0, 0]) if k == 8 else None))
    assert DEVICE_FORCE_LIMIT >= 40.0  # the strongest desk devices give ~35-40 N


def test_a_killed_recordings_journal_is_checked_too(tmp_path):
    p = tmp_path / "killed.h5"
    w = SessionWriter(p, _meta())
    for k in range(N):
        w.append(t=1.0 if k == 12 else k * 1e-3, probe_position=[0, 0, 1e-8])
    w._stream.stop()  # the thread wrote every tick; the writer is never closed (a killed process)
    w._file.close()
    _OPEN_WRITERS.discard(w)  # as after a kill: nobody closes it
    with pytest.raises(SessionError, match=r"tick 13: t = 0\.013\d* s is not after tick 12"):
        load_session(p, allow_incomplete=True)


def test_a_full_disk_is_flagged_at_the_next_append(tmp_path, caplog):
    """The journal's write fails with ENOSPC in the writer thread: the next append flags it
    (failed, unrecorded ticks counted, one warning) without raising; close says it again."""
    p = tmp_path / "run.h5"
    w = SessionWriter(p, _meta(), flush_interval=0.01)
    real = w._file.write

    def full(kind, parts):
        if kind == _journal.TICKS:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(kind, parts)

    w._file.write = full
    w.append(t=0.0, probe_position=[0, 0, 1e-8])
    st = w._stream
    with st.lock:  # the writer thread notifies after each write attempt (every flush_interval)
        assert st.lock.wait_for(lambda: st.error is not None, timeout=10.0)
    assert not w.failed  # nothing has looked yet
    with caplog.at_level(logging.WARNING, logger="arsurf.sessions.writer"):
        w.append(t=1e-3, probe_position=[0, 0, 1e-8])
        w.append(t=2e-3, probe_position=[0, 0, 1e-8])
    assert w.failed and isinstance(w.write_error, OSError) and w.write_error.errno == errno.ENOSPC
    assert w.unrecorded_ticks == 3
    warnings = [r for r in caplog.records if "No space left" in r.getMessage()]
    assert len(warnings) == 1 and "\n" not in warnings[0].getMessage()
    with pytest.raises(SessionError, match="No space left on device"):
        w.close()


def test_a_planted_link_where_the_session_goes_is_never_written(tmp_path):
    """A second user plants the session's name (or the old run.h5.part) as a link to a victim."""
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o1777)
    victim = tmp_path / "victim"
    victim.write_bytes(b"precious")
    os.symlink(victim, shared / "run.h5.part")
    _write(shared / "run.h5")
    assert victim.read_bytes() == b"precious"
    assert load_session(shared / "run.h5").n_ticks == N
    os.symlink(victim, shared / "other.h5")
    with pytest.raises(SessionError, match="symbolic link"):
        SessionWriter(shared / "other.h5", _meta())
    assert victim.read_bytes() == b"precious"
