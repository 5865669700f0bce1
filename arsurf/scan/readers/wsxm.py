"""WSxM (Nanotec/UAM) image reader (``.top``, ``.stp``, ``.tom``, ``.ch*``).

Library: our own parser (no maintained Python reader exists); the layout and scaling follow
Gwyddion's ``wsxmfile.c``.

Format: text header starting ``WSxM file copyright ...``, ``SxM Image file``,
``Image header size: N``; ``[Section]`` lines and ``Key: Value`` lines, ending with
``[Header end]``. ``[General Info]`` gives ``Number of columns``, ``Number of rows``,
``Z Amplitude`` (e.g. ``12.5 nm``) and, in newer files, ``Image Data Type`` (``double``,
``float``, ``integer``, ``short``); ``[Control]`` gives ``X Amplitude`` and ``Y Amplitude``
(e.g. ``2 um``). The data start at byte N, little-endian, row by row.

Z scaling: floating-point data (``double``/``float``) are heights in the unit of
``Z Amplitude``; integer data (``short``, the legacy default, and ``integer``) are rescaled so
that their max - min spans ``Z Amplitude`` (as Gwyddion does).
Orientation: WSxM writes the top line first (Gwyddion shows the first stored row at the top),
so rows are flipped: row 0 = bottom. Pixel spacing: ``dx = X Amplitude / columns``.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from arsurf.errors import CorruptScan
from arsurf.scan.readers._common import (
    Channel,
    check_scale,
    check_shape,
    flip_rows,
    frombuffer,
    make_scan,
    parse_float,
    parse_int,
    parse_unit,
    select_channel,
)

EXTENSIONS = (".top", ".stp", ".tom", ".ch1", ".ch2", ".ch3")
FORMAT = "wsxm"
MAGIC = b"WSxM file copyright"
_TYPES = {"double": "<f8", "float": "<f4", "integer": "<i4", "short": "<i2"}


def sniff(head: bytes) -> bool:
    """True when the file starts with ``WSxM file copyright``."""
    return head.startswith(MAGIC)


def _quantity(path, text: str, what: str) -> tuple[float, str, float]:
    """(value in SI, SI base unit, factor of the written unit to SI) of ``'12.5 nm'``."""
    m = re.match(r"^\s*([-+]?[\d.]+(?:[eE][-+]?\d+)?)\s*(.*)$", text or "")
    if not m:
        raise CorruptScan(f"{path}: {what} {text!r} is not '<number> <unit>'")
    value = parse_float(path, m.group(1), what)
    unit = m.group(2).strip()
    if unit in ("a.u.", ""):
        return value, "", 1.0
    factor, base = parse_unit(unit)
    return value * factor, base, factor


def read(path: Path | str, channel: str | None = None):
    """Read a WSxM image (one channel per file; its name is the header's ``Acquisition channel``)."""
    buf = Path(path).read_bytes()
    if not sniff(buf[:64]):
        raise CorruptScan(f"{path}: missing the 'WSxM file copyright' line")
    m = re.search(rb"Image header size:\s*(\d+)", buf[:400])
    if not m:
        raise CorruptScan(f"{path}: no 'Image header size' line")
    hsize = int(m.group(1))
    if not 0 < hsize <= len(buf):
        raise CorruptScan(f"{path}: header size {hsize} does not fit in the {len(buf)}-byte file")
    text = buf[:hsize].decode("latin-1")
    meta: dict[str, str] = {}
    section = None
    for line in text.replace("\r", "").split("\n"):
        s = line.strip()
        if s.startswith("[") and s.endswith("]"):
            section = s[1:-1]
            continue
        if section and ":" in s:
            k, v = s.split(":", 1)
            meta[f"{section}::{k.strip()}"] = v.strip()
    if section != "Header end":
        raise CorruptScan(f"{path}: the header does not end with [Header end]")
    nx = parse_int(path, meta.get("General Info::Number of columns", ""), "Number of columns")
    ny = parse_int(path, meta.get("General Info::Number of rows", ""), "Number of rows")
    check_shape(path, nx, ny)
    kind = meta.get("General Info::Image Data Type", "short").strip().lower()
    if kind not in _TYPES:
        raise CorruptScan(f"{path}: unknown Image Data Type {kind!r} (expected one of {sorted(_TYPES)})")
    data = frombuffer(path, buf, hsize, _TYPES[kind], nx * ny, "the WSxM data").reshape(ny, nx)
    zamp, zunit, zfactor = _quantity(path, meta.get("General Info::Z Amplitude", ""), "Z Amplitude")
    if kind in ("double", "float"):
        z = data * zfactor
    else:
        zamp = check_scale(path, zamp, "Z Amplitude")
        span = float(np.nanmax(data) - np.nanmin(data)) if data.size else 0.0
        z = data * (zamp / span) if span > 0 else np.zeros_like(data)
    xr, xu, _ = _quantity(path, meta.get("Control::X Amplitude", ""), "X Amplitude")
    yr, yu, _ = _quantity(path, meta.get("Control::Y Amplitude", meta.get("Control::X Amplitude", "")), "Y Amplitude")
    if xu != "m" or yu != "m":
        raise CorruptScan(f"{path}: X/Y Amplitude units are not lengths ({xu!r}, {yu!r})")
    name = meta.get("General Info::Acquisition channel", meta.get("Control::Acquisition channel", "Topography"))
    chan = Channel(name or "Topography", key=0, unit=zunit or "", direction=None)
    chan = select_channel(path, [chan], channel)
    return make_scan(
        path, FORMAT, flip_rows(z), xr / nx, yr / ny, chan, [chan], rows_flipped=True,
        z_factor=1.0, z_unit=zunit,
        instrument={"software": "WSxM", "head": meta.get("Head Settings::Head type")},
        extra={"data_type": kind, "header": {k: v for k, v in meta.items() if len(v) < 200}},
    )
