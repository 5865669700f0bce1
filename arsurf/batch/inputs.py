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
from typing import Sequence

from arsurf.errors import BatchError

__all__ = ["Item", "collect_inputs", "item_key", "item_file_name"]


@dataclass(frozen=True)
class Item:
    """One unit of work: ``key`` (unique in the table), ``path`` (the input file, absolute) and
    ``params`` (the sweep's grid point as ``((name, value), ...)``, SI; empty otherwise)."""

    key: str
    path: str
    params: tuple = ()
    root: str = ""  #: the folder every input of the batch is under (what a session may name)



def _scan_suffixes() -> tuple[str, ...]:
    from arsurf.scan.io import _ext_map

    return tuple(sorted(_ext_map()))


def collect_inputs(inputs: Sequence[str | os.PathLike], suffixes: Sequence[str] | None = None, *,
                   exclude: str | os.PathLike | None = None) -> tuple[list[Path], Path]:
    """The input files of a batch, sorted, and the folder they are named relative to.

    Each input is a file (taken as it is), a folder (its files whose extension is in
    ``suffixes``, case-insensitive, not recursive) or a glob pattern (``*``, ``?``, ``[...]``;
    ``**`` recurses; every regular file it matches). Files inside ``exclude`` (the batch's output
    folder) are left out.

    Returns
    -------
    files : list of Path
        Absolute (symbolic links are not resolved), without duplicates.
    root : Path
        The deepest folder holding all of them (item keys are relative to it).

    Raises
    ------
    BatchError
        An input does not exist, a folder holds no such file, a pattern matches nothing.
    """
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    if not inputs:
        raise BatchError("no input given: name scan files, folders or glob patterns")
    wanted = {s.lower() for s in (suffixes if suffixes is not None else _scan_suffixes())}
    skips = set() if exclude is None else {Path(os.path.abspath(exclude)), Path(exclude).resolve()}
    found: dict[Path, None] = {}
    for entry in inputs:
        text = os.fspath(entry)
        if glob.has_magic(text):
            matches = [Path(m) for m in sorted(glob.glob(text, recursive=True)) if Path(m).is_file()]
            if not matches:
                raise BatchError(f"no file matches the pattern {text!r}")
        elif os.path.isdir(text):
            matches = sorted(p for p in Path(text).iterdir() if p.is_file() and p.suffix.lower() in wanted)
            if not matches:
                raise BatchError(f"folder {text!r} holds no input file (extensions {', '.join(sorted(wanted))}); "
                                 "name the files or a glob pattern to take others")
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
    return files, root


def item_key(path: Path, root: Path) -> str:
    return path.relative_to(root).as_posix()


def item_file_name(key: str) -> str:
    """A file name for an item key: ``/`` -> ``__``; characters a file system refuses -> ``_``."""
    name = key.replace("/", "__")
    return "".join("_" if c in '<>:"\\|?*' or ord(c) < 32 else c for c in name)

