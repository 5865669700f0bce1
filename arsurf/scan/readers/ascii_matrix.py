"""Plain ASCII matrix reader (``.txt``, ``.asc``, ``.dat``, ``.csv``): one image row per line.

Library: our own (numpy parsing); no package is needed for whitespace/comma/semicolon
separated numbers.

Calibration: Gwyddion's "ASCII data matrix" export writes ``#`` comment lines such as
``# Channel: Z raw``, ``# Width: 4.000 µm``, ``# Height: 4.000 µm``, ``# Value units: m``;
they are used when present. A bare matrix says nothing about its pixel spacing or height
unit: then ``dx``/``dy`` (metres) and ``z_unit`` must be passed to :func:`arsurf.load_scan`,
else :class:`MissingCalibration` is raised. Nothing is guessed.

Orientation: the first line is the top row of the image (as Gwyddion exports and shows it),
so rows are flipped: row 0 = bottom. Pixel spacing ``dx = Width / columns`` (Gwyddion).
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from arsurf.errors import CorruptScan
from arsurf.scan.readers._common import Channel, check_shape, flip_rows, make_scan, parse_unit, select_channel
from arsurf.errors import MissingCalibration

EXTENSIONS = (".txt", ".asc", ".dat", ".csv", ".mat")
FORMAT = "ascii-matrix"
_SPLIT = re.compile(r"[\s,;]+")


def _numeric_rows(text: str, limit: int | None = None) -> tuple[list[str], list[list[str]]]:
    comments, rows = [], []
    for line in text.splitlines():
        s = line.strip()
        if not s:
            continue
        if s[0] in "#%":
            comments.append(s.lstrip("#% "))
            continue
        rows.append([t for t in _SPLIT.split(s) if t])
        if limit is not None and len(rows) >= limit:
            break
    return comments, rows


def _is_number(tok: str) -> bool:
    try:
        float(tok)
    except ValueError:
        return False
    return True


def sniff_columns(head: bytes) -> int:
    """Number of columns if ``head`` looks like a numeric table (constant width >= 2), else 0."""
    if b"\x00" in head:
        return 0
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError:
        text = head.decode("latin-1")
    lines = text.splitlines()
    if len(head) >= 4096 and lines:
        lines = lines[:-1]  # the last line of a cut head may be partial
    _, rows = _numeric_rows("\n".join(lines), limit=8)
    if not rows:
        return 0
    widths = {len(r) for r in rows}
    if len(widths) != 1 or not all(_is_number(t) for r in rows for t in r):
        return 0
    return widths.pop()


def sniff(head: bytes) -> bool:
    """True for a numeric table of constant width >= 2 (the xyz sniffer runs first)."""
    return sniff_columns(head) >= 2


def _length(text: str) -> float | None:
    m = re.match(r"^\s*([-+]?[\d.]+(?:[eE][-+]?\d+)?)\s*(\S+)", text)
    if not m:
        return None
    f, base = parse_unit(m.group(2))
    return float(m.group(1)) * f if base == "m" else None


def read(path: Path | str, channel: str | None = None, *, dx: float | None = None,
         dy: float | None = None, z_unit: str | None = None):
    """Read an ASCII matrix; ``dx``/``dy`` (m) and ``z_unit`` are needed when the file has no header."""
    text = Path(path).read_bytes().decode("utf-8", errors="replace")
    comments, rows = _numeric_rows(text)
    if not rows:
        raise CorruptScan(f"{path}: no numeric rows")
    widths = {len(r) for r in rows}
    if len(widths) != 1:
        raise CorruptScan(f"{path}: rows have different numbers of values {sorted(widths)[:5]} (truncated or ragged)")
    try:
        data = np.array(rows, dtype=np.float64)
    except ValueError:
        raise CorruptScan(f"{path}: a value is not a number") from None
    ny, nx = data.shape
    check_shape(path, nx, ny)
    info = {}
    for c in comments:
        k, sep, v = c.partition(":")
        if sep:
            info[k.strip().lower()] = v.strip()
    width = _length(info.get("width", ""))
    height = _length(info.get("height", ""))
    if dx is None:
        dx = width / nx if width else None
    if dy is None:
        dy = height / ny if height else None
    if dx is None or dy is None:
        raise MissingCalibration(
            f"{path} is a bare ASCII matrix without '# Width:'/'# Height:' lines; pass its pixel spacing "
            "in metres, e.g. load_scan(path, dx=1e-8, dy=1e-8) (arsurf CLI: --dx-nm 10 --dy-nm 10)"
        )
    unit = z_unit if z_unit is not None else info.get("value units")
    if unit is None:
        raise MissingCalibration(
            f"{path} does not say the unit of its values (no '# Value units:' line); pass it, e.g. "
            "load_scan(path, ..., z_unit='nm') (arsurf CLI: --z-unit nm)"
        )
    chan = Channel(info.get("channel", "Height"), key=0, unit=unit)
    chan = select_channel(path, [chan], channel)
    return make_scan(path, FORMAT, flip_rows(data), dx, dy, chan, [chan], rows_flipped=True,
                     extra={"header": info})
