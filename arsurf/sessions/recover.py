"""Recovering a recording that never closed: its journal's intact ticks written into its session file."""
from __future__ import annotations

import os
from pathlib import Path

from arsurf.errors import SessionFileNotFound
from arsurf.sessions import journal as _journal
from arsurf.sessions.journal import journal_path
from arsurf.sessions.reader import _journal_session
from arsurf.sessions.writer import _fsync_dir, _merge_journal

__all__ = ["recover_session"]



def recover_session(path: str | os.PathLike) -> Path:
    """Write the ticks of an unfinished recording's journal into its session file.

    Parameters
    ----------
    path : path-like
        The session file the recording was writing (``run.h5``) or its journal
        (``run.h5.journal``).

    Returns
    -------
    Path
        The session file, sealed, ``complete`` False (with the reason) unless the recording
        was closed normally and only the final write failed. The journal is deleted.

    Raises
    ------
    SessionError
        No journal, or one without an intact header.
    """
    p = Path(path)
    if p.name.endswith(_journal.JOURNAL_SUFFIX):
        jpath, target = p, p.with_name(p.name[:-len(_journal.JOURNAL_SUFFIX)])
    else:
        jpath, target = journal_path(p), p
    if not jpath.is_file():
        raise SessionFileNotFound(f"there is no journal {str(jpath)!r} to recover")
    s = _journal_session(jpath, True, target)
    index = _journal.scan_journal(jpath)
    _merge_journal(index, target, complete=s.complete, reason=s.attrs.get("aborted", ""),
                   created=s.attrs["created"] or None)
    jpath.unlink()
    _fsync_dir(jpath.parent)
    return target
