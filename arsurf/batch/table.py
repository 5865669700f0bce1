"""The results table of a batch (``results.csv``): one row per finished item, appended and
fsynced as each finishes, a torn last line cut off before appending, read back latest-row-per-item.

Floats are written with ``repr`` (exact round trip), booleans as 0/1, ``None`` as an empty cell;
the columns carry their unit in their names (:mod:`arsurf.units`).
"""
from __future__ import annotations

import csv
import os
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from arsurf._files import check_target
from arsurf.errors import BatchError

__all__ = ["TABLE", "BASE_COLUMNS", "MAX_REASON", "ResultTable", "cell", "one_line_reason", "read_results",
           "repair_table"]

TABLE = "results.csv"
#: the columns every table starts with
BASE_COLUMNS = ("item", "status", "error")
#: longest error reason kept in the table (characters)
MAX_REASON = 400


def one_line_reason(exc: BaseException) -> str:
    """``Type: first line of the message``, at most :data:`MAX_REASON` characters."""
    text = str(exc).strip().splitlines()
    line = f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__
    return line if len(line) <= MAX_REASON else line[:MAX_REASON - 3] + "..."


def cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, (bool, np.bool_)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    return str(value).replace("\r", " ").replace("\n", " ")


class ResultTable:
    """``results.csv``: the header once, then one row per item, flushed and fsynced as it comes."""

    def __init__(self, path: Path, columns: tuple[str, ...]):
        self.path = path
        self.columns = columns
        check_target(path, "results table", error=BatchError)  # a planted link is refused, never appended to
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o666)
        new = os.fstat(fd).st_size == 0
        self.fh = os.fdopen(fd, "a", encoding="utf-8", newline="")
        self.writer = csv.writer(self.fh, lineterminator="\n")
        if new:
            self._write(columns)

    def _write(self, cells) -> None:
        self.writer.writerow(cells)
        self.fh.flush()
        os.fsync(self.fh.fileno())

    def append(self, row: Mapping) -> None:
        self._write([cell(row.get(c)) for c in self.columns])

    def close(self) -> None:
        self.fh.close()


def repair_table(path: Path) -> None:
    """Cut a torn last line (the batch killed while writing it) so appending keeps the table valid."""
    if not path.exists():
        return
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        with open(path, "r+b") as fh:
            fh.truncate(data.rfind(b"\n") + 1)


def read_results(path: str | os.PathLike, columns: Sequence[str] | None = None) -> dict[str, dict[str, str]]:
    """The rows of a results table, the latest per item (a resumed item's last attempt), as strings.

    Parameters
    ----------
    path : path-like
        ``results.csv`` (or the batch's output folder).
    columns : sequence of str, optional
        The header the table must have (BatchError otherwise).

    Returns
    -------
    dict
        item -> {column: cell}. A torn last line is ignored.
    """
    path = Path(path)
    if path.is_dir():
        path = path / TABLE
    if not path.exists():
        return {}
    text = path.read_text(encoding="utf-8")
    if text and not text.endswith("\n"):
        text = text[:text.rfind("\n") + 1]
    lines = list(csv.reader(text.splitlines()))
    if not lines:
        return {}
    header = tuple(lines[0])
    if columns is not None and header != tuple(columns):
        raise BatchError(f"{str(path)!r} has the columns {list(header)}, not those of this pipeline "
                         f"{list(columns)}; choose another output folder")
    return {row[0]: dict(zip(header, row)) for row in lines[1:] if len(row) == len(header)}
