r"""Recording a session: :class:`SessionWriter` streams ticks to a crash-safe journal and writes the sealed ``.h5``.

The file it writes is described in :mod:`arsurf.sessions.schema`; :func:`write_h5` (also used for
replay outputs) writes any such file atomically, with checksums and a seal
(:mod:`arsurf.sessions.sealed`); :func:`record_loop_tick` is the one way a haptic loop's tick is
recorded.

Recording survives the process dying
------------------------------------
:class:`SessionWriter` streams the ticks, while it records, into ``<path>.journal``
(:mod:`arsurf.sessions.journal`: an append-only file of self-checking records, written and
fsynced by a background thread at least every ``flush_interval`` = 50 ms; why a journal
rather than HDF5 SWMR or segment files is argued there). :meth:`SessionWriter.append` writes
one row into a preallocated chunk and returns: O(1), no allocation, never blocks (when the disk
falls behind by more than the chunk pool, ticks are dropped, counted in ``dropped_ticks``).
Memory stays flat for any session length. :meth:`SessionWriter.close` merges the journal into
an exclusive temporary beside ``<path>`` (:func:`arsurf._files.atomic_write`: created
``O_EXCL | O_NOFOLLOW`` under an unpredictable name; gzip, checksums, seal), fsyncs it, renames it
over ``<path>`` (a symbolic link there is refused) and deletes the journal. If the process is killed (SIGKILL, crash, power cut) the journal remains:
:func:`~arsurf.sessions.reader.load_session` with ``allow_incomplete=True`` (``arsurf replay
--allow-incomplete``) reads every tick of its intact records - everything appended more than
~50 ms (plus one write) before the kill - and :func:`~arsurf.sessions.recover.recover_session`
turns it into a session file marked incomplete. With
``handle_signals=True`` (the process owns the recording, as the command line does) SIGTERM and
SIGINT unwind the recording block and the file is closed with every tick, marked incomplete
with the signal as the reason.

Examples
--------
>>> import tempfile, os, numpy as np
>>> from arsurf.force.cantilever import Cantilever
>>> from arsurf.contact.maugis_dugdale import MaugisDugdale
>>> from arsurf.sessions.reader import load_session
>>> d = tempfile.mkdtemp()
>>> from arsurf.assembly import session_metadata
>>> meta = session_metadata(scan={"path": "scan.npz", "sha256": "0" * 64, "channel": None,
...                               "processing": {"level": "plane", "sigma": 0.0, "inpaint": True}},
...                         tip_radius=20e-9, contact=MaugisDugdale(20e-9, 50e9, 0.1),
...                         cantilever=Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27))
>>> with SessionWriter(os.path.join(d, "s.h5"), meta) as w:
...     for k in range(3):
...         w.append(t=k * 1e-3, probe_position=(1e-7, 1e-7, 3e-8 - k * 1e-9), depth=-1e-8)
>>> s = load_session(os.path.join(d, "s.h5"))
>>> s.n_ticks, s.ticks["probe_position"].shape, bool(np.isnan(s.ticks["force"]).all()), s.verified
(3, (3, 3), True, True)
"""
from __future__ import annotations

import atexit
import datetime
import json
import logging
import os
import signal
import threading
import weakref
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from arsurf._files import atomic_write, check_target
from arsurf.assembly import _jsonable, check_metadata
from arsurf.errors import RecordingInterrupted, SessionError
from arsurf.sessions import journal as _journal
from arsurf.sessions.journal import journal_path
from arsurf.sessions.schema import (FORMAT, FORMAT_VERSION, TUBE_POSES, _attr, _canonical, _dataset_hasher, _h5py,
                                    _layout, _session_fields, _sha, contact_fields)
from arsurf.sessions.sealed import SEAL_SIZE, seal_open
from arsurf.units import UNITS_ATTR

_log = logging.getLogger(__name__)

__all__ = ["FLUSH_INTERVAL", "SessionWriter", "record_loop_tick", "write_h5"]

#: ticks per chunk of the recorder (and per journal record), chunks in its pool
_CHUNK_TICKS = 256
_QUEUE_CHUNKS = 32
#: the recorder writes the chunk being filled at least this often, s
FLUSH_INTERVAL = 0.05


def record_loop_tick(writer: "SessionWriter", loop, t: float, state) -> None:
    """Append the tick a :class:`~arsurf.haptics.loop.HapticLoop` just ran to ``writer``.

    The one way a loop is recorded (``arsurf demo``, the live loops of ``arsurf view``): the
    device sample ``state`` (:class:`~arsurf.haptics.device.DeviceState`: stylus position,
    velocity, buttons), what the tick computed (``loop.out``: probe, tip, energy, passivity
    damping, signals, probe force, device force, safety flags), the contact of ``loop.model.out``
    (:func:`~arsurf.sessions.schema.contact_fields`) and, with a scene, the tube poses after the tick. ``t`` is the
    loop time the tick was given (s). A button word the loop took as malformed is recorded as
    the no-press it was given (0); a sample the loop refused (:mod:`arsurf.haptics.samples`: its
    flag is in ``safety_flags``) is recorded as the last good sample the tick ran on.

    Examples
    --------
    >>> # f = loop.step(state, now); record_loop_tick(writer, loop, now, state)
    """
    from arsurf.haptics.loop import LOOP_OUT, _valid_buttons

    o = loop.out
    get = LOOP_OUT.get
    extra = {} if loop.scene is None else {TUBE_POSES.name: loop.scene.poses}
    writer.append(t=t, stylus_position=loop.stylus_position, stylus_velocity=loop.stylus_velocity,
                  buttons=_valid_buttons(state.buttons)[0], probe_position=get(o, "probe"),
                  probe_velocity=get(o, "probe_velocity"), tip_position=get(o, "tip"), energy=get(o, "energy"),
                  passivity_damping=get(o, "passivity_damping"), signals=get(o, "signals"),
                  force=get(o, "probe_force"), device_force=get(o, "device_force"),
                  safety_flags=int(get(o, "safety_flags")),
                  **contact_fields(loop.model.record(loop.model.out)), **extra)


# ---------------------------------------------------------------------------------------------
# writing HDF5


def _fsync_dir(path: Path) -> None:
    _journal._fsync_dir(path)


def _rows_per_chunk(row_bytes: int) -> int:
    return int(min(4096, max(1, (1 << 20) // max(row_bytes, 1))))


class _H5Out:
    """A sealed HDF5 file being written: root attrs, ``/metadata`` texts, ``/ticks`` datasets.

    The datasets are created with their final shape and filled by blocks in row order
    (:meth:`write`); each carries its SI unit in a ``units`` attribute (:mod:`arsurf.units`);
    :meth:`finish` adds the ``checksums`` attribute, seals the file, fsyncs it and renames it
    over ``path``. Equal inputs give equal bytes (no timestamps, fixed chunks).
    """

    def __init__(self, path: Path, attrs: Mapping, metadata: Mapping, shapes: Mapping[str, tuple],
                 dtypes: Mapping[str, np.dtype], units: Mapping[str, str]):
        h5py = _h5py()
        self.path = Path(path)
        self._f = None
        # an exclusive temporary in the target's folder (arsurf._files): a planted link is never written
        self._cm = atomic_write(self.path, "wb", what="session file", error=SessionError)
        self._fh = self._cm.__enter__()
        self.part = self._fh.temp
        try:
            self._f = h5py.File(self._fh, "w", userblock_size=SEAL_SIZE)
            f = self._f
            self._attrs = {}
            for key, value in attrs.items():
                f.attrs[key] = value
                self._attrs[key] = _attr(value)
            texts = {key: json.dumps(metadata[key], sort_keys=True, allow_nan=False) for key in sorted(metadata)}
            mg = f.create_group("metadata")
            for key, text in texts.items():
                mg.attrs[key] = text
            self._sums = {"algorithm": "sha256", "metadata": _sha(_canonical(texts))}
            tg = f.create_group("ticks")
            self._ds, self._hash, self._next = {}, {}, {}
            row_bytes = max(np.dtype(dtypes[n]).itemsize * int(np.prod(shapes[n][1:], dtype=np.int64))
                            for n in shapes) if shapes else 1
            self.block = _rows_per_chunk(row_bytes)
            for name, shape in shapes.items():
                dt = np.dtype(dtypes[name]).newbyteorder("<")
                opts = ({"chunks": (min(shape[0], self.block), *shape[1:]), "compression": "gzip",
                         "compression_opts": 4, "shuffle": True} if shape[0] else {})
                self._ds[name] = tg.create_dataset(name, shape=shape, dtype=dt, track_times=False, **opts)
                self._ds[name].attrs[UNITS_ATTR] = units[name]
                self._hash[name] = _dataset_hasher(dt, shape)
                self._next[name] = 0
        except BaseException:
            self.abort()
            raise

    def write(self, name: str, start: int, block: np.ndarray) -> None:
        """Write rows ``start .. start + len(block)`` of dataset ``name`` (in order)."""
        ds = self._ds[name]
        if start != self._next[name]:
            raise SessionError(f"internal: /ticks/{name} written out of order (row {start}, expected "
                               f"{self._next[name]})")
        block = np.ascontiguousarray(block, dtype=ds.dtype)
        n = block.shape[0]
        if n:
            ds[start:start + n] = block
            self._hash[name].update(block.data)
        self._next[name] = start + n

    def finish(self) -> Path:
        try:
            for name, ds in self._ds.items():
                if self._next[name] != ds.shape[0]:
                    raise SessionError(f"internal: /ticks/{name} has {self._next[name]} of {ds.shape[0]} rows")
                self._sums[f"ticks/{name}"] = self._hash[name].hexdigest()
            self._sums["attrs"] = _sha(_canonical(self._attrs))
            self._f.attrs["checksums"] = json.dumps(self._sums, sort_keys=True)
            self._f.close()
            seal_open(self._fh)
            cm, self._cm = self._cm, None
            cm.__exit__(None, None, None)  # fsynced, renamed over the path, folder fsynced
        except BaseException:
            self.abort()
            raise
        return self.path

    def abort(self) -> None:
        try:
            if self._f is not None:
                self._f.close()
        except Exception:  # pragma: no cover - already closed or never opened
            pass
        if self._cm is not None:  # the temporary is removed, the target left as it was
            cm, self._cm = self._cm, None
            cm.__exit__(SessionError, SessionError("aborted"), None)


def write_h5(path: str | os.PathLike, attrs: Mapping[str, Any], metadata: Mapping[str, Any],
             datasets: Mapping[str, np.ndarray], units: Mapping[str, str]) -> Path:
    """Write root ``attrs``, ``/metadata`` (JSON per key) and ``/ticks/<name>`` datasets atomically.

    The file goes to an exclusive temporary beside ``path`` (:func:`arsurf._files.atomic_write`)
    with ``checksums`` and a seal (:func:`arsurf.sessions.sealed.seal_open`), is fsynced and renamed
    over ``path`` (a symbolic link there is refused); each dataset
    gets the ``units`` attribute ``units[name]`` (:mod:`arsurf.units`); datasets carry no
    timestamps, so equal inputs give equal bytes. Used for sessions and replay outputs.
    """
    arrays = {name: np.asarray(a) for name, a in datasets.items()}
    missing = sorted(set(arrays) - set(units))
    if missing:
        raise SessionError(f"internal: no unit given for the dataset(s) {missing}")
    out = _H5Out(Path(path), attrs, metadata, {n: a.shape for n, a in arrays.items()},
                 {n: a.dtype for n, a in arrays.items()}, units)
    try:
        for name, a in arrays.items():
            for start in range(0, a.shape[0], out.block):
                out.write(name, start, a[start:start + out.block])
    except BaseException:
        out.abort()
        raise
    return out.finish()


def _utc_now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def _merge_journal(index: _journal.JournalIndex, path: Path, *, complete: bool, reason: str,
                   created: str | None) -> Path:
    """Write the ticks of a scanned journal into the sealed session file ``path`` (streaming)."""
    from arsurf import __version__

    header = index.header
    metadata = header["metadata"]
    fields = _session_fields(metadata)
    n = index.n_ticks
    attrs = {"format": FORMAT, "format_version": np.int64(FORMAT_VERSION),
             "arsurf_version": str(header.get("arsurf_version", __version__)),
             "created": created if created is not None else str(header.get("started", _utc_now())), "units": "SI",
             "complete": np.bool_(complete), "n_ticks": np.int64(n), "dropped_ticks": np.int64(index.total_dropped)}
    if not complete:
        attrs["aborted"] = reason or "the recording stopped before the writer was closed"
    lay = index.layout
    out = _H5Out(path, attrs, metadata, {name: (n, *fields[name][1]) for name in fields},
                 {name: np.dtype(fields[name][0].dtype) for name in fields},
                 {name: fields[name][0].unit for name in fields})
    try:
        block = out.block
        stage = [np.empty((block, *s), dtype=d) for d, s in zip(lay.dtypes, lay.shapes)]
        state = {"done": 0, "fill": 0}

        def flush():
            k = state["fill"]
            if k:
                for name, buf in zip(lay.names, stage):
                    out.write(name, state["done"], buf[:k])
                state["done"] += k
                state["fill"] = 0

        def sink(row, arrays):
            m = arrays[0].shape[0]
            at = 0
            while at < m:
                take = min(block - state["fill"], m - at)
                for buf, a in zip(stage, arrays):
                    buf[state["fill"]:state["fill"] + take] = a[at:at + take]
                state["fill"] += take
                at += take
                if state["fill"] == block:
                    flush()

        _journal.read_rows(index, sink)
        flush()
    except BaseException:
        out.abort()
        raise
    return out.finish()


# ---------------------------------------------------------------------------------------------
# the recorder

_OPEN_WRITERS: "weakref.WeakSet[SessionWriter]" = weakref.WeakSet()


@atexit.register
def _close_open_writers() -> None:  # pragma: no cover - runs at interpreter exit
    for w in list(_OPEN_WRITERS):
        try:
            w.close(complete=False, reason="the process exited without closing the writer")
        except Exception:
            pass


def _abandon(stream: _journal.TickStreamer, file: _journal.JournalFile) -> None:
    stream.stop()
    file.close()


class SessionWriter:
    """Record a session tick by tick, streamed to a crash-safe journal; the ``.h5`` is written at :meth:`close`.

    Parameters
    ----------
    path : path-like
        The session file (``.h5``; not a symbolic link); written at :meth:`close` through an
        exclusive temporary (:func:`arsurf._files.atomic_write`). While
        recording, ticks stream into ``<path>.journal`` (:func:`~arsurf.sessions.journal.journal_path`), which must not
        exist.
    metadata : dict
        Session metadata (:func:`arsurf.assembly.session_metadata`); checked here, so a recording that could
        not be replayed fails before it starts.
    capacity : int
        Ticks per chunk (1..65536): the writer thread takes a chunk when it is full, and the
        chunk being filled every ``flush_interval``.
    created : str, optional
        The ``created`` attribute (default: the UTC time at :meth:`close`); pass a fixed value
        to make the file byte-reproducible.
    queue_chunks : int
        Chunks the disk may lag behind (``queue_chunks * capacity`` ticks, 8192 by default:
        8 s at 1 kHz) before ticks are dropped.
    flush_interval : float, s
        The longest a tick waits before the writer thread writes and fsyncs it (0.001..1).
    when_full : {"drop", "wait"}
        ``"drop"`` (real-time loops): :meth:`append` never blocks; when the disk is so far
        behind that the pool is empty, the chunk being filled is dropped and counted
        (``dropped_ticks`` in the file). ``"wait"`` (batch producers faster than the disk):
        :meth:`append` waits for the writer thread instead.
    fsync : bool
        fsync the journal at every flush (power-loss safety; a killed process loses nothing
        written either way).
    handle_signals : bool
        Install SIGINT/SIGTERM handlers (only from the main thread; the previous ones come back
        at :meth:`close`) that raise :class:`~arsurf.errors.RecordingInterrupted`, so a ``with``
        block unwinds and the file is closed with every tick, marked incomplete with the
        signal as the reason. For processes that own the recording (command lines), not
        libraries. Ticks may be appended from another thread (a live loop's servo thread): the
        signal then interrupts the main thread, which should stop that thread before the
        ``with`` block closes the writer.

    Notes
    -----
    :meth:`append` costs one lock and one numpy row assignment per given field (a few
    microseconds in all) and allocates nothing: memory stays flat for any session length.
    Used as a context manager, the file is written at exit; if the block raised, it is still
    written but marked ``complete=False`` (with the reason in ``aborted``), and
    :func:`~arsurf.sessions.reader.load_session` refuses it unless asked. A writer never closed is closed (incomplete)
    at interpreter exit; a process killed outright leaves the journal, which
    :func:`~arsurf.sessions.reader.load_session` (``allow_incomplete=True``) and
    :func:`~arsurf.sessions.recover.recover_session` read.

    Examples
    --------
    >>> # with SessionWriter("run.h5", meta) as w:
    >>> #     w.append(t=t, probe_position=c, probe_velocity=v, signals=s, force=f)
    """

    def __init__(self, path: str | os.PathLike, metadata: Mapping, *, capacity: int = _CHUNK_TICKS,
                 created: str | None = None, queue_chunks: int = _QUEUE_CHUNKS,
                 flush_interval: float = FLUSH_INTERVAL, when_full: str = "drop", fsync: bool = True,
                 handle_signals: bool = False):
        from arsurf import __version__

        self.path = Path(path)
        if self.path.is_dir():
            raise SessionError(f"session path {str(self.path)!r} is a directory; pass a file name such as run.h5")
        if not self.path.parent.is_dir():
            raise SessionError(f"the folder of the session file {str(self.path)!r} does not exist; create it first")
        check_target(self.path, "session file", error=SessionError)  # a planted link: refused before recording
        self.metadata = _jsonable(metadata, "metadata")
        check_metadata(self.metadata)
        capacity = int(capacity)
        if not 1 <= capacity <= _journal.MAX_RECORD_TICKS:
            raise SessionError(f"`capacity` must be 1..{_journal.MAX_RECORD_TICKS} ticks per chunk (got {capacity})")
        queue_chunks = int(queue_chunks)
        if not 1 <= queue_chunks <= 4096:
            raise SessionError(f"`queue_chunks` must be 1..4096 (got {queue_chunks})")
        flush_interval = float(flush_interval)
        if not 1e-3 <= flush_interval <= 1.0:
            raise SessionError(f"`flush_interval` must be 0.001..1 s (got {flush_interval}); it bounds how long a "
                               "tick waits before it is on disk")
        if when_full not in ("drop", "wait"):
            raise SessionError(f"`when_full` must be 'drop' or 'wait' (got {when_full!r})")
        self._created = created
        self._fields = _session_fields(self.metadata)
        self._index = {name: i for i, name in enumerate(self._fields)}
        self._fills = [f.fill for f, _ in self._fields.values()]
        layout = _layout(self._fields)
        self.journal = journal_path(self.path)
        header = {"format": _journal.JOURNAL_FORMAT, "journal_version": _journal.JOURNAL_VERSION,
                  "session_format_version": FORMAT_VERSION, "arsurf_version": __version__, "started": _utc_now(),
                  "metadata": self.metadata, "fields": layout.describe()}
        self._file = _journal.JournalFile(self.journal, header, fsync=fsync)
        self._stream = _journal.TickStreamer(layout, self._file, chunk_ticks=capacity, queue_chunks=queue_chunks,
                                             interval=flush_interval, when_full=when_full)
        self._closed = False
        #: True once an append saw that the journal could not be written (full disk, I/O error)
        self.failed = False
        self._written: Path | None = None
        self._end: dict | None = None
        self._signal: str | None = None
        self._busy = False      # inside append's critical section: a signal waits until it ends
        self._pending = False
        self._old_handlers: dict = {}
        if handle_signals and threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._old_handlers[sig] = signal.signal(sig, self._on_signal)
        _OPEN_WRITERS.add(self)
        # a writer dropped without close: stop its thread, close the journal (kept, recoverable)
        self._finalizer = weakref.finalize(self, _abandon, self._stream, self._file)
        self._finalizer.atexit = False  # at exit, _close_open_writers closes live writers properly

    def _on_signal(self, signum, frame) -> None:
        self._signal = signal.Signals(signum).name
        if self._busy:  # never unwind half-way through a chunk hand-over
            self._pending = True
            return
        raise RecordingInterrupted(f"recording to {str(self.path)!r} stopped by {self._signal}")

    def _restore_signals(self) -> None:
        for sig, old in self._old_handlers.items():
            try:
                signal.signal(sig, old)
            except (ValueError, TypeError):  # pragma: no cover - not the main thread any more
                pass
        self._old_handlers = {}

    @property
    def n_ticks(self) -> int:
        """Ticks appended and kept so far (dropped ones excluded)."""
        return self._stream.appended - self._stream.dropped

    @property
    def dropped_ticks(self) -> int:
        """Ticks dropped because the disk fell behind (``when_full="drop"``)."""
        return self._stream.dropped

    @property
    def write_error(self) -> BaseException | None:
        """The error that stopped the journal (a full disk: ``OSError`` ENOSPC), or None.

        Set by the writer thread at the failed write (it writes at least every
        ``flush_interval``); the next :meth:`append` then flags it (:attr:`failed`, a warning
        on the ``arsurf.sessions.writer`` logger) without raising, so a real-time loop keeps running and
        :meth:`close` says it again."""
        return self._stream.error

    @property
    def unrecorded_ticks(self) -> int:
        """Ticks appended but not in the journal because writing failed (0 while it works)."""
        st = self._stream
        return 0 if st.error is None else max(0, st.appended - st.dropped - st.written)

    def _flag_failure(self) -> None:
        self.failed = True
        _log.warning("recording to %r failed: %s; from tick %d on nothing more is recorded (the journal %r "
                     "keeps the %d ticks before; free disk space and recover_session it)", str(self.path),
                     self._stream.error, self._stream.written, str(self.journal), self._stream.written)

    def _clear_row(self, arrays, i: int) -> None:
        for a, fill in zip(arrays, self._fills):
            a[i] = fill

    def append(self, **fields) -> None:
        """Record one tick.

        Parameters
        ----------
        **fields
            ``t`` (s) and ``probe_position`` ((3,) m) are required; every other field of
            :data:`~arsurf.sessions.schema.TICK_FIELDS` is optional (missing: NaN, or the integer fill value), and so are
            ``safety_flags`` (the loop's flag word, :data:`~arsurf.sessions.schema.SAFETY_FLAGS`) and ``tube_poses``
            ((k, 3): x, y, angle per tube) when the metadata has a tube scene.

        Raises
        ------
        SessionError
            Unknown field name, wrong shape, missing ``t``/``probe_position``, writer closed.
        """
        if self._closed:
            raise SessionError(f"the session writer of {str(self.path)!r} is closed; open a new one")
        st = self._stream
        index = self._index
        if threading.current_thread() is not threading.main_thread():
            # signal handlers run in the main thread: one arriving now interrupts the main thread
            # at once (it is not inside this append), never this one (a live loop's servo thread)
            self._append_locked(st, index, fields)
            return
        self._busy = True
        try:
            self._append_locked(st, index, fields)
        finally:
            self._busy = False
            if self._pending:
                self._pending = False
                raise RecordingInterrupted(f"recording to {str(self.path)!r} stopped by {self._signal}")

    def _append_locked(self, st, index, fields) -> None:
        with st.lock:
            c = st.current
            i = c.n
            arrays = c.arrays
            try:
                for name, value in fields.items():
                    arrays[index[name]][i] = value
            except KeyError:
                self._clear_row(arrays, i)
                unknown = sorted(set(fields) - set(index))
                hint = (" (tube_poses needs a tube scene in the metadata: tubes=TubeScene.to_metadata())"
                        if TUBE_POSES.name in unknown else "")
                raise SessionError(f"unknown session field(s) {unknown}; the fields are "
                                   f"{list(self._fields)}{hint}") from None
            except (ValueError, TypeError) as exc:
                self._clear_row(arrays, i)
                bad, shape = self._fields[name]
                rows = bad.row_text if name != TUBE_POSES.name else f"{shape[0]} x 3 numbers"
                raise SessionError(f"session field {name!r} must be {rows} per tick "
                                   f"({bad.doc}); got {value!r}: {exc}") from None
            if "t" not in fields or "probe_position" not in fields:
                self._clear_row(arrays, i)
                raise SessionError(f"every tick needs `t` (s) and `probe_position` ((3,) m); got only {sorted(fields)}")
            st.commit_locked()
            if st.error is not None and not self.failed:  # one attribute read per tick while the disk works
                self._flag_failure()

    def close(self, complete: bool = True, reason: str = "") -> Path:
        """Stop recording, merge the journal into the sealed session file and return its path.

        Idempotent once it succeeded. If writing the ``.h5`` fails (full disk...), the error is
        raised and the journal stays, complete, for :func:`~arsurf.sessions.recover.recover_session` (or another
        :meth:`close`).
        """
        if self._written is not None:
            return self.path
        if not self._closed:
            self._closed = True
            self._restore_signals()
            st = self._stream
            st.stop()
            if self._signal is not None and complete is not True:
                reason = f"stopped by {self._signal}"
            error = st.error
            if error is not None:
                complete, reason = False, f"the journal could not be written: {error}"
                if not self.failed:  # the write failed after the last append (a slow fsync, a fast loop)
                    self._flag_failure()
            self._end = {"complete": bool(complete), "reason": reason or "", "n_ticks": st.written,
                         "dropped_ticks": st.dropped,
                         "created": self._created if self._created is not None else _utc_now()}
            try:
                if error is None:
                    self._file.write(_journal.END, [json.dumps(self._end, sort_keys=True).encode()])
                    self._file.sync()
            finally:
                self._file.close()
            if error is not None:
                _OPEN_WRITERS.discard(self)
                raise SessionError(f"recording to {str(self.path)!r} failed: the journal {str(self.journal)!r} could "
                                   f"not be written ({error}); its {st.written} ticks are kept "
                                   f"(load_session(..., allow_incomplete=True)), the {self.unrecorded_ticks} "
                                   "appended after them were not recorded") from error
        end = self._end
        index = _journal.scan_journal(self.journal)
        _merge_journal(index, self.path, complete=end["complete"], reason=end["reason"], created=end["created"])
        self.journal.unlink()
        _fsync_dir(self.journal.parent)
        self._written = self.path
        _OPEN_WRITERS.discard(self)
        return self.path

    def __enter__(self) -> "SessionWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        elif self._signal is not None:
            self.close(complete=False, reason=f"stopped by {self._signal}")
        else:
            self.close(complete=False, reason=f"{exc_type.__name__}: {exc}")
