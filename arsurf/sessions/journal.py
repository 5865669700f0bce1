r"""The recording journal: ticks streamed to disk in sealed records, readable after any crash.

While a session records, its ticks go to ``<session>.journal``, an append-only file of
records. Each record seals itself:

======  ========  ===========================================================================
offset  bytes     content
======  ========  ===========================================================================
0       4         magic ``b"ASJ1"``
4       4         kind (uint32 LE): 1 header, 2 ticks, 3 end
8       8         payload length L (uint64 LE)
16      L         payload
16 + L  32        SHA-256 of bytes ``[0, 16 + L)`` (magic, kind, length and payload)
======  ========  ===========================================================================

* header (first record): UTF-8 JSON ``{"format": "arsurf-session-journal", "journal_version": 1,
  "arsurf_version", "started" (UTC ISO 8601), "metadata", "fields": [[name, dtype, row shape],
  ...]}``;
* ticks: ``seq, first, n`` (3 x uint64 LE: record number from 0, index of the first tick
  counting dropped ones, number of ticks 1..65536) then, field by field in header order, the
  ``n`` rows of that field as little-endian bytes;
* end (written by a normal close): UTF-8 JSON ``{"complete", "reason", "created", "n_ticks",
  "dropped_ticks"}``.

Why a journal (and not HDF5 SWMR or one file per segment). The file is only ever appended to,
and every record carries its length and a SHA-256 of itself, so whatever moment the writer
dies at - SIGKILL, power cut, full disk - the file is a run of intact records followed by at
most one torn record, which the reader recognises (length past the end of the file, or a
digest that does not match) and drops. That is crash consistency by construction, with no
library in the path that must itself survive the crash: an HDF5 file killed while its
B-trees and free lists are being updated can be unreadable (SWMR avoids that only with the
latest file format, one writer process and careful flushing, and a killed SWMR writer still
leaves the file marked as open), and segment files need a create + fsync + rename + directory
fsync per flush and a folder of 72 000 files per hour at 20 flushes/s, where the journal needs
one ``write`` and one ``fsync``. The payload is raw (uncompressed: ~0.38 kB per tick, 1.4 GB
per hour at 1 kHz) so the reader never inflates anything and never needs more memory than the
file holds; :meth:`arsurf.sessions.writer.SessionWriter.close` merges the journal into the
compressed, sealed ``.h5`` and deletes it.

:class:`TickStreamer` moves the ticks off the real-time thread: the caller of ``append`` writes
one row into a preallocated chunk under a lock, and a writer thread writes full chunks, and
every ``interval`` seconds the chunk being filled, as records, then fsyncs (one fsync for
everything it wrote in that round). The chunks come from a fixed pool (``queue_chunks``): when
the disk falls so far behind that the pool is empty, the chunk being filled is dropped (its
ticks counted in ``dropped_ticks`` and the gap visible in the next record's ``first``) rather
than blocking the caller (``when_full="drop"``); batch producers that must not lose ticks use
``when_full="wait"``.
"""
from __future__ import annotations

import hashlib
import json
import os
import struct
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from arsurf.errors import SessionError

__all__ = ["JOURNAL_FORMAT", "JOURNAL_VERSION", "JOURNAL_SUFFIX", "JournalFile", "JournalIndex", "scan_journal",
           "read_rows", "TickStreamer", "Layout", "HEADER", "TICKS", "END", "journal_path"]

JOURNAL_FORMAT = "arsurf-session-journal"
JOURNAL_VERSION = 1
JOURNAL_SUFFIX = ".journal"
MAGIC = b"ASJ1"
HEADER, TICKS, END = 1, 2, 3
_HEAD = struct.Struct("<4sIQ")
_WRITEV = hasattr(os, "writev")  # not on Windows
_TICKS = struct.Struct("<3Q")
_DIGEST = 32
#: the most ticks one record holds, and the largest payload a reader accepts
MAX_RECORD_TICKS = 1 << 16
MAX_PAYLOAD = 1 << 28
MAX_JSON = 1 << 24


def journal_path(path: str | os.PathLike) -> Path:
    """The journal a recording to ``path`` streams into: ``<path>.journal``."""
    p = Path(path)
    return p.with_name(p.name + JOURNAL_SUFFIX)


@dataclass(frozen=True)
class Layout:
    """The per-tick fields of a journal: names, dtypes (little-endian), row shapes, fill values."""

    names: tuple
    dtypes: tuple
    shapes: tuple
    fills: tuple

    @property
    def row_bytes(self) -> tuple:
        return tuple(np.dtype(d).itemsize * int(np.prod(s, dtype=np.int64)) for d, s in zip(self.dtypes, self.shapes))

    def describe(self) -> list:
        """JSON form stored in the header: ``[[name, dtype, [row shape]], ...]``."""
        return [[n, np.dtype(d).str, list(s)] for n, d, s in zip(self.names, self.dtypes, self.shapes)]


# ---------------------------------------------------------------------------------------------
# records


def _record(kind: int, parts: list) -> list[memoryview]:
    """A record as buffers to write in order: head, the parts (bytes or C-contiguous arrays, not
    copied) and the SHA-256 of everything before it."""
    views = [memoryview(p).cast("B") for p in parts]
    head = _HEAD.pack(MAGIC, kind, sum(v.nbytes for v in views))
    h = hashlib.sha256(head)
    for v in views:
        h.update(v)
    return [memoryview(head), *views, memoryview(h.digest())]


class JournalFile:
    """Append-only writer of journal records (not thread-safe: one writer thread uses it).

    Parameters
    ----------
    path : path-like
        Created; it must not exist (an unfinished recording's journal is never overwritten).
    header : dict
        The header record (JSON).
    fsync : bool
        fsync after each :meth:`sync` (power-loss safety; a killed process loses nothing
        written either way, the page cache survives it).
    """

    def __init__(self, path, header: dict, fsync: bool = True):
        self.path = Path(path)
        self._fsync = fsync
        try:
            self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o644)
        except FileExistsError:
            raise SessionError(f"the journal {str(self.path)!r} of an unfinished recording exists; recover it with "
                               f"arsurf.sessions.recover.recover_session({str(self.path)!r}) or delete it") from None
        self.write(HEADER, [json.dumps(header, sort_keys=True, allow_nan=False).encode()])
        self.sync()
        _fsync_dir(self.path.parent)

    def write(self, kind: int, parts) -> None:
        buffers = _record(kind, parts)
        while buffers:  # one system call per record where there is writev; a short write goes on
            done = os.writev(self._fd, buffers) if _WRITEV else os.write(self._fd, buffers[0])
            while buffers and done >= buffers[0].nbytes:
                done -= buffers.pop(0).nbytes
            if buffers:
                buffers[0] = buffers[0][done:]

    def sync(self) -> None:
        if self._fsync:
            os.fsync(self._fd)

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path if str(path) else ".", os.O_RDONLY)
    except OSError:  # pragma: no cover - no directory fds (Windows)
        return
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover
        pass
    finally:
        os.close(fd)


def _read_exact(fh, n: int) -> bytes | None:
    data = fh.read(n)
    return data if len(data) == n else None


@dataclass
class JournalIndex:
    """What :func:`scan_journal` found: header, tick records, end record and the damaged tail."""

    path: Path
    header: dict
    layout: Layout
    records: list = field(default_factory=list)  # (payload offset, payload length, first, n)
    end: dict | None = None
    n_ticks: int = 0
    dropped_ticks: int = 0
    size: int = 0
    valid_bytes: int = 0
    stop_reason: str = ""

    @property
    def discarded_bytes(self) -> int:
        """Bytes after the last intact record (a torn record, or damage)."""
        return self.size - self.valid_bytes

    @property
    def total_dropped(self) -> int:
        """Ticks dropped while recording: gaps between records, and after the last one (end record)."""
        told = (self.end or {}).get("dropped_ticks")
        told = told if isinstance(told, int) and not isinstance(told, bool) and told >= 0 else 0
        return max(self.dropped_ticks, told)


def _json_payload(payload: bytes, what: str) -> dict:
    try:
        obj = json.loads(payload.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise SessionError(f"{what} is not valid JSON ({exc})") from None
    if not isinstance(obj, dict):
        raise SessionError(f"{what} is not a JSON object")
    return obj


def _records(fh, size: int) -> Iterator[tuple[int, int, int, bytes | None, str]]:
    """Yield ``(offset, kind, length, payload, "")`` per intact record; last ``(offset, 0, 0, None, why)``."""
    pos = 0
    while True:
        if pos == size:
            yield pos, 0, 0, None, ""
            return
        head = _read_exact(fh, _HEAD.size)
        if head is None:
            yield pos, 0, 0, None, f"a torn record header at byte {pos}"
            return
        magic, kind, length = _HEAD.unpack(head)
        if magic != MAGIC or kind not in (HEADER, TICKS, END):
            yield pos, 0, 0, None, f"no record at byte {pos} (bad magic or kind)"
            return
        if length > min(size - pos - _HEAD.size - _DIGEST, MAX_PAYLOAD):
            yield pos, 0, 0, None, f"a torn record at byte {pos} (it announces {length} bytes)"
            return
        payload = _read_exact(fh, length)
        digest = _read_exact(fh, _DIGEST)
        if payload is None or digest is None or hashlib.sha256(head + payload).digest() != digest:
            yield pos, 0, 0, None, f"a damaged record at byte {pos} (its SHA-256 does not match)"
            return
        yield pos, kind, length, payload, ""
        pos += _HEAD.size + length + _DIGEST


def _layout_from(header: dict, what: str) -> Layout:
    fields = header.get("fields")
    if not isinstance(fields, list) or not fields:
        raise SessionError(f"{what}: header has no field list")
    names, dtypes, shapes = [], [], []
    for item in fields:
        ok = (isinstance(item, list) and len(item) == 3 and isinstance(item[0], str) and isinstance(item[1], str)
              and item[1] in ("<f8", "<i4") and isinstance(item[2], list) and len(item[2]) <= 2
              and all(isinstance(s, int) and not isinstance(s, bool) and 1 <= s <= 4096 for s in item[2]))
        if not ok:
            raise SessionError(f"{what}: header field {item!r} is not [name, '<f8'|'<i4', [row shape]]")
        names.append(item[0])
        dtypes.append(item[1])
        shapes.append(tuple(item[2]))
    if len(set(names)) != len(names):
        raise SessionError(f"{what}: header lists a field twice")
    return Layout(tuple(names), tuple(dtypes), tuple(shapes), (None,) * len(names))


def scan_journal(path) -> JournalIndex:
    """Read a journal's records, checking each, and index the intact ones (no tick data is kept).

    Stops at the first record that is torn or damaged (normally the record a crash cut); the
    :class:`JournalIndex` says where and why. Memory: O(number of records).

    Raises
    ------
    SessionError
        No intact header record, or a header that is not a session journal, or records out of
        sequence (a file that was not written by :class:`JournalFile`).
    """
    p = Path(path)
    what = f"journal {str(p)!r}"
    size = p.stat().st_size
    with open(p, "rb") as fh:
        it = _records(fh, size)
        pos, kind, length, payload, why = next(it)
        if kind != HEADER:
            raise SessionError(f"{what} has no intact header record ({why or 'the first record is not a header'}); "
                               "nothing can be recovered from it")
        if length > MAX_JSON:
            raise SessionError(f"{what}: header record of {length} bytes is too large")
        header = _json_payload(payload, f"{what} header")
        if header.get("format") != JOURNAL_FORMAT or header.get("journal_version") != JOURNAL_VERSION:
            raise SessionError(f"{what} is not an {JOURNAL_FORMAT} version {JOURNAL_VERSION} file "
                               f"(format {header.get('format')!r}, version {header.get('journal_version')!r})")
        layout = _layout_from(header, what)
        row = sum(layout.row_bytes)
        index = JournalIndex(path=p, header=header, layout=layout, size=size)
        index.valid_bytes = _HEAD.size + length + _DIGEST
        seq = 0
        for pos, kind, length, payload, why in it:
            if payload is None:
                index.stop_reason = why
                break
            if index.end is not None:
                index.stop_reason = f"a record after the end record at byte {pos}"
                break
            if kind == TICKS:
                if length < _TICKS.size:
                    index.stop_reason = f"a ticks record too short at byte {pos}"
                    break
                s, first, n = _TICKS.unpack_from(payload)
                if s != seq or first < index.n_ticks + index.dropped_ticks or not 1 <= n <= MAX_RECORD_TICKS \
                        or length != _TICKS.size + n * row:
                    index.stop_reason = (f"an inconsistent ticks record at byte {pos} (record {s}, first tick {first}, "
                                         f"{n} ticks, {length} bytes)")
                    break
                index.dropped_ticks += first - (index.n_ticks + index.dropped_ticks)
                index.records.append((pos + _HEAD.size + _TICKS.size, length - _TICKS.size, first, n))
                index.n_ticks += n
                seq += 1
            elif kind == END:
                if length > MAX_JSON:
                    index.stop_reason = f"an end record too large at byte {pos}"
                    break
                index.end = _json_payload(payload, f"{what} end record")
            else:
                index.stop_reason = f"a second header at byte {pos}"
                break
            index.valid_bytes = pos + _HEAD.size + length + _DIGEST
    return index


def read_rows(index: JournalIndex, sink: Callable[[int, list], None]) -> None:
    """Call ``sink(row, arrays)`` for every intact ticks record (rows ``row .. row + n``).

    ``arrays`` are read-only views of the record, one per field, shaped ``(n, *row shape)``.
    Each record's SHA-256 is checked again (the file could have changed since
    :func:`scan_journal`). Memory: one record at a time.
    """
    lay = index.layout
    widths = lay.row_bytes
    row = 0
    with open(index.path, "rb") as fh:
        for offset, length, first, n in index.records:
            start = offset - _HEAD.size - _TICKS.size
            fh.seek(start)
            blob = _read_exact(fh, _HEAD.size + _TICKS.size + length + _DIGEST)
            if blob is None or hashlib.sha256(blob[:-_DIGEST]).digest() != blob[-_DIGEST:]:
                raise SessionError(f"journal {str(index.path)!r} changed while it was being read")
            at = _HEAD.size + _TICKS.size
            arrays = []
            for dt, shape, w in zip(lay.dtypes, lay.shapes, widths):
                arrays.append(np.frombuffer(blob, dtype=dt, count=n * w // np.dtype(dt).itemsize,
                                            offset=at).reshape(n, *shape))
                at += n * w
            sink(row, arrays)
            row += n


# ---------------------------------------------------------------------------------------------
# streaming


class _Chunk:
    __slots__ = ("arrays", "n", "first")

    def __init__(self, layout: Layout, cap: int):
        self.arrays = [np.full((cap, *s), f, dtype=d) for d, s, f in zip(layout.dtypes, layout.shapes, layout.fills)]
        self.n = 0
        self.first = 0

    def clear(self, fills) -> None:
        n = self.n
        for a, f in zip(self.arrays, fills):
            a[:n] = f
        self.n = 0


class TickStreamer:
    """Chunks of ticks filled by the caller, written to a :class:`JournalFile` by a thread.

    Parameters
    ----------
    layout : Layout
    journal : JournalFile
    chunk_ticks : int
        Ticks per chunk (and at most per record).
    queue_chunks : int
        Chunks in the pool besides the one being filled: the backlog the disk may have
        (``queue_chunks * chunk_ticks`` ticks) before ticks are dropped.
    interval : float, s
        The chunk being filled is written at least this often (a tick reaches the disk at
        most ``interval`` plus one write and fsync after it was appended).
    when_full : {"drop", "wait"}
        What :meth:`lock`'s caller does when the pool is empty: drop the chunk being filled
        (counted; never blocks), or wait for the writer thread.

    Notes
    -----
    The caller holds :attr:`lock` while it fills row :attr:`current`.n of :attr:`current`
    and then calls :meth:`commit_locked`; the writer thread takes the lock only to swap
    chunks (O(1)). Nothing is allocated after construction.
    """

    def __init__(self, layout: Layout, journal: JournalFile, *, chunk_ticks: int, queue_chunks: int,
                 interval: float, when_full: str):
        self.layout = layout
        self._journal = journal
        self._cap = chunk_ticks
        self._interval = interval
        self._wait = when_full == "wait"
        self._free = [_Chunk(layout, chunk_ticks) for _ in range(queue_chunks)]
        self.current = _Chunk(layout, chunk_ticks)
        self._queue: list[_Chunk] = []
        self.lock = threading.Condition(threading.Lock())
        self._stopping = False
        self.error: BaseException | None = None
        self.appended = 0      # ticks handed to commit (kept or dropped)
        self.dropped = 0
        self.written = 0       # ticks in intact records
        self._seq = 0
        self._thread = threading.Thread(target=self._run, name="arsurf-session-writer", daemon=True)
        self._thread.start()

    # --- caller side (lock held) -------------------------------------------------------------
    def commit_locked(self) -> None:
        """The row ``current.n`` is filled: count it, and hand the chunk over when it is full."""
        c = self.current
        c.n += 1
        self.appended += 1
        if c.n == self._cap:
            self._handoff_locked()

    def _handoff_locked(self) -> None:
        c = self.current
        while not self._free and self._wait and self.error is None and self._thread.is_alive():
            self.lock.wait(0.1)  # releases the lock: the writer thread may take `c` meanwhile
            if self.current is not c:
                return
        if self._free:
            self._queue.append(c)
            nxt = self._free.pop()
            nxt.first = self.appended
            self.current = nxt
            self.lock.notify_all()
        else:  # the disk is behind: drop this chunk, never block the real-time caller
            self.dropped += c.n
            c.clear(self.layout.fills)
            c.first = self.appended

    # --- writer thread -----------------------------------------------------------------------
    def _run(self) -> None:
        deadline = time.monotonic() + self._interval
        while True:
            with self.lock:
                while not self._queue and not self._stopping:
                    left = deadline - time.monotonic()
                    if left <= 0:
                        break
                    self.lock.wait(left)
                batch, self._queue = self._queue, []
                now = time.monotonic()
                stop = self._stopping
                if (stop or now >= deadline) and self.current.n:
                    if stop:
                        batch.append(self.current)
                    elif self._free:
                        batch.append(self.current)
                        nxt = self._free.pop()
                        nxt.first = self.appended
                        self.current = nxt
                if now >= deadline:
                    deadline = now + self._interval
            if batch and self.error is None:
                try:
                    for c in batch:
                        if c.n:  # a record holds 1..65536 ticks
                            self._write(c)
                    self._journal.sync()
                except BaseException as exc:  # disk full, I/O error: reported at close
                    self.error = exc
            with self.lock:
                for c in batch:
                    if c is not self.current:
                        c.clear(self.layout.fills)
                        self._free.append(c)
                self.lock.notify_all()
            if stop:
                return

    def _write(self, c: _Chunk) -> None:
        n = c.n
        parts = [_TICKS.pack(self._seq, c.first, n)] + [a[:n] for a in c.arrays]
        self._journal.write(TICKS, parts)
        self._seq += 1
        self.written += n

    def stop(self) -> None:
        """Write everything appended so far and end the thread (idempotent)."""
        with self.lock:
            self._stopping = True
            self.lock.notify_all()
        self._thread.join()

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

