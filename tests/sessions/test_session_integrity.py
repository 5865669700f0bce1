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
from tests.support.session_samples import _meta

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


def _device_meta(max_force=3.3, workspace=(0.12, 0.16, 0.12)):
    meta = _meta()
    meta["device"] = {"interface": "virtual", "name": "virtual", "max_force": max_force, "workspace": list(workspace)}
    return meta


def test_the_recorded_device_limits_are_used_when_given(tmp_path):
    """The ``device`` record the live loop, the bridge view and the demos write bounds the stylus per
    axis (half-extent plus as much again, as the live sample check) and the device force (max_force
    plus 1 %), far inside the fixed bounds of an old session (1 m, 100 N)."""
    meta = _device_meta()
    load_session(_write(tmp_path / "ok.h5", meta=meta, edit=lambda k, f: f.update(
        device_force=[3.3, 0, 0], stylus_position=[0.119, -0.159, 0.119])))
    with pytest.raises(SessionError, match=r"tick 5: device_force .*recorded device's max_force"):
        load_session(_write(tmp_path / "f.h5", meta=meta,
                            edit=lambda k, f: f.update(device_force=[4.0, 0, 0]) if k == 5 else None))
    # 0.2 m along y: a fifth of the fixed 1 m, outside the device's 0.16 m per-axis bound
    with pytest.raises(SessionError, match=r"tick 8: stylus_position = \[0\.0, 0\.2, 0\.0\] m is outside the "
                                           r"recorded device workspace"):
        load_session(_write(tmp_path / "w.h5", meta=meta,
                            edit=lambda k, f: f.update(stylus_position=[0.0, 0.2, 0.0]) if k == 8 else None))
    with pytest.raises(SessionError, match=r"tick 2: stylus_position = \[0\.13, 0\.0, 0\.0\] m"):
        load_session(_write(tmp_path / "x.h5", meta=meta,
                            edit=lambda k, f: f.update(stylus_position=[0.13, 0.0, 0.0]) if k == 2 else None))
    assert DEVICE_FORCE_LIMIT >= 40.0  # the strongest desk devices give ~35-40 N


def test_a_recorded_device_cannot_widen_the_fixed_bounds(tmp_path):
    """A crafted record claiming a 1 km workspace and a 1 MN device is capped at 1 m and 100 N."""
    meta = _device_meta(max_force=1e6, workspace=(1e3, 1e3, 1e3))
    with pytest.raises(SessionError, match=r"tick 4: stylus_position .*per axis \[1\.0, 1\.0, 1\.0\] m"):
        load_session(_write(tmp_path / "w.h5", meta=meta,
                            edit=lambda k, f: f.update(stylus_position=[0, 0, 2.0]) if k == 4 else None))
    with pytest.raises(SessionError, match=r"tick 6: device_force .*pushes harder"):
        load_session(_write(tmp_path / "f.h5", meta=meta,
                            edit=lambda k, f: f.update(device_force=[0, 200.0, 0]) if k == 6 else None))


SEALED_EDITS = {
    "t": (lambda a: a.__setitem__(9, a[8]), r"tick 9: t = .* is not after tick 8"),
    "stylus_position": (lambda a: a.__setitem__(12, [0.0, 0.0, 0.3]), r"tick 12: stylus_position .*device workspace"),
    "device_force": (lambda a: a.__setitem__(3, [0.0, 0.0, -5.0]), r"tick 3: device_force .*max_force"),
    "probe_position": (lambda a: a.__setitem__(20, [0.0, 0.5, 0.0]), r"tick 20: probe_position .*scanner's travel"),
}


@pytest.mark.parametrize("field", sorted(SEALED_EDITS))
def test_a_resealed_session_that_makes_no_sense_is_refused(tmp_path, field):
    """Ticks edited after recording, checksums and seal redone: the bytes are 'intact', the content
    is still checked, in-process and isolated."""
    import h5py

    from tests.support.hdf5_attacks import reseal_session

    p = _write(tmp_path / "s.h5", meta=_device_meta())
    edit, match = SEALED_EDITS[field]
    with h5py.File(p, "r+") as f:
        a = f["ticks"][field][()]
        edit(a)
        f["ticks"][field][...] = a
    reseal_session(p)
    for isolate in (False, True):
        with pytest.raises(SessionError, match=match) as info:
            load_session(p, isolate=isolate)
        assert "\n" not in str(info.value)


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


def _fill_disk(w):
    """Every tick record the writer ``w`` writes from now on fails with ENOSPC (a full disk)."""
    real = w._file.write

    def full(kind, parts):
        if kind == _journal.TICKS:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(kind, parts)

    w._file.write = full


def test_a_full_disk_is_flagged_at_the_next_append(tmp_path, caplog):
    """The journal's write fails with ENOSPC in the writer thread: the next append flags it
    (failed, unrecorded ticks counted, one warning) without raising; close says it again."""
    p = tmp_path / "run.h5"
    w = SessionWriter(p, _meta(), flush_interval=0.01)
    _fill_disk(w)
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


def test_a_write_that_fails_after_the_last_append_is_still_warned_once(tmp_path, caplog):
    """The loop may end before the writer thread meets the full disk (a demo faster than real time, a
    slow fsync of the previous record): close then gives the same one warning an append would have,
    before its error, so the command line says it as every other recording does."""
    p = tmp_path / "run.h5"
    w = SessionWriter(p, _meta(), flush_interval=1.0)  # nothing written before close
    _fill_disk(w)
    for k in range(5):
        w.append(t=k * 1e-3, probe_position=[0, 0, 1e-8])
    assert w.write_error is None and not w.failed
    with caplog.at_level(logging.WARNING, logger="arsurf.sessions.writer"):
        with pytest.raises(SessionError, match="the 5 appended after them were not recorded"):
            w.close()
    warnings = [r for r in caplog.records if "No space left" in r.getMessage()]
    assert w.failed and len(warnings) == 1 and "nothing more is recorded" in warnings[0].getMessage()


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
