"""The inputs of a batch: the files it takes (folders, globs, lists) and the items they make.

An item's key is the input's path relative to the common folder of all inputs (``/`` kept); its
file name (:func:`item_file_name`) writes ``/`` as ``__``. The sweep's grid items are made by
:func:`arsurf.batch.pipelines.make_items`.
"""
from __future__ import annotations

import glob
import os
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple, Sequence

from arsurf.errors import BatchError

__all__ = ["Inputs", "Item", "collect_inputs", "item_key", "item_file_name", "skipped_note"]


@dataclass(frozen=True)
class Item:
    """One unit of work: ``key`` (unique in the table), ``path`` (the input file, absolute) and
    ``params`` (the sweep's grid point as ``((name, value), ...)``, SI; empty otherwise)."""

    key: str
    path: str
    params: tuple = ()
    root: str = ""  #: the folder every input of the batch is under (what a session may name)



class Inputs(NamedTuple):
    """What :func:`collect_inputs` found: ``files`` (absolute, sorted), ``root`` (the folder item keys
    are relative to) and ``skipped`` (the files of named folders that are not inputs, sorted)."""

    files: list[Path]
    root: Path
    skipped: list[Path]


def _is_scan(path: Path) -> bool:
    """True when :func:`arsurf.scan.io.detect_format` names a format for ``path``: by its content
    (NanoScope ``.di``/``.001``, a renamed file...), else by its extension, as ``load_scan`` reads it."""
    from arsurf.errors import ScanError
    from arsurf.scan.io import detect_format

    try:
        detect_format(path)
    except ScanError:
        return False
    return True


def _taken(path: Path, suffixes: Sequence[str] | None) -> bool:
    if suffixes is None:
        return _is_scan(path)
    return path.suffix.lower() in {s.lower() for s in suffixes}


def skipped_note(skipped: Sequence[Path], shown: int = 5) -> str:
    """One line naming the files a folder held that are not inputs (``""``: none).

    >>> skipped_note([Path("a/notes.md"), Path("a/log.txt")])
    'skipped: 2 files, not inputs: notes.md, log.txt'
    """
    if not skipped:
        return ""
    names = ", ".join(p.name for p in skipped[:shown])
    more = f" and {len(skipped) - shown} more" if len(skipped) > shown else ""
    return f"skipped: {len(skipped)} file{'s' if len(skipped) != 1 else ''}, not inputs: {names}{more}"


def collect_inputs(inputs: Sequence[str | os.PathLike], suffixes: Sequence[str] | None = None, *,
                   exclude: str | os.PathLike | None = None) -> Inputs:
    """The input files of a batch, sorted, the folder they are named relative to, and what was left out.

    Each input is a file (taken as it is), a folder (not recursive: with ``suffixes`` None, every
    file :func:`arsurf.scan.io.load_scan` would read, detected by its **content** then its
    extension, e.g. a NanoScope ``.di``; else its files whose extension is in ``suffixes``,
    case-insensitive) or a glob pattern (``*``, ``?``, ``[...]``; ``**`` recurses; every regular
    file it matches). Files inside ``exclude`` (the batch's output folder) are left out.

    Returns
    -------
    Inputs
        ``files`` absolute (symbolic links are not resolved), without duplicates; ``root`` the
        deepest folder holding all of them (item keys are relative to it); ``skipped`` the files of
        the named folders that are not inputs (neither a scan nor of the pipeline's kind).

    Raises
    ------
    BatchError
        An input does not exist, a folder holds no such file, a pattern matches nothing.
    """
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    if not inputs:
        raise BatchError("no input given: name scan files, folders or glob patterns")
    skips = set() if exclude is None else {Path(os.path.abspath(exclude)), Path(exclude).resolve()}
    found: dict[Path, None] = {}
    left: dict[Path, None] = {}
    for entry in inputs:
        text = os.fspath(entry)
        if glob.has_magic(text):
            matches = [Path(m) for m in sorted(glob.glob(text, recursive=True)) if Path(m).is_file()]
            if not matches:
                raise BatchError(f"no file matches the pattern {text!r}")
        elif os.path.isdir(text):
            matches, others = [], []
            for p in sorted(p for p in Path(text).iterdir() if p.is_file()):
                (matches if _taken(p, suffixes) else others).append(p)
            if not matches:
                kind = "scan file (arsurf formats lists the formats)" if suffixes is None else \
                    f"file with the extension {', '.join(sorted(suffixes))}"
                raise BatchError(f"folder {text!r} holds no {kind}; name the files or a glob pattern to take others")
            for p in others:
                left.setdefault(Path(os.path.abspath(p)), None)
        elif os.path.isfile(text):
            matches = [Path(text)]
        else:
            raise BatchError(f"input {text!r} does not exist (a file, a folder or a glob pattern)")
        for m in matches:
            path = Path(os.path.abspath(m))  # symbolic links kept: a linked copy is an item of its own
            if any(s == p or s in p.parents for s in skips for p in (path, path.resolve())):
                continue
            found.setdefault(path, None)
    files = sorted(found)
    if not files:
        raise BatchError(f"every input is inside the output folder {os.fspath(exclude)!r}; choose another output "
                         "folder")
    root = Path(os.path.commonpath([str(p.parent) for p in files]))
    return Inputs(files, root, sorted(p for p in left if p not in found))


def item_key(path: Path, root: Path) -> str:
    return path.relative_to(root).as_posix()


def item_file_name(key: str) -> str:
    """A file name for an item key: ``/`` -> ``__``; characters a file system refuses -> ``_``."""
    name = key.replace("/", "__")
    return "".join("_" if c in '<>:"\\|?*' or ord(c) < 32 else c for c in name)

