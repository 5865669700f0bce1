"""Nanonis ``.sxm`` reader.

Library: our own parser. ``nanonispy`` 1.1 crashes on numpy >= 1.24 (``np.float``), and
``pySPM.SXM`` 0.6.3 cannot be used on untrusted files: it loops forever on a truncated header
(``while l != b":SCANIT_END:"`` with ``readline()`` returning ``b""`` at end of file) and on a
file without the ``\\x1a\\x04`` data marker (``while f.read(1) != b"\\x1a"``); it also seeks
``4 * size`` bytes per channel even for ``DOUBLE`` data, does not flip ``up`` scans or backward
channels, and imports matplotlib (about 3 s). On the real Au(111) file our forward Z equals
pySPM's array up to our row flip (checked in the tests).

Format (Nanonis "SXM file format"): text header of ``:TAG:`` lines each followed by its value
lines, ending with ``:SCANIT_END:``; then ``\\x1a\\x04``; then, for each channel of
``:DATA_INFO:`` (columns Channel, Name, Unit, Direction, Calibration, Offset), the forward and,
when Direction is ``both``, the backward image, ``pixels x lines`` values of ``SCANIT_TYPE``
(``FLOAT MSBFIRST`` = big-endian float32), in acquisition order. Values are already in the
channel's unit (``Z`` in m).

Orientation (as Gwyddion's nanonis module): backward images are stored as scanned, right to
left, and are mirrored in x; the first stored line is the first scanned one, which is the top
of the frame for ``SCAN_DIR down`` (flipped here so that row 0 is the bottom) and the bottom
for ``SCAN_DIR up`` (kept). Pixel spacing ``dx = SCAN_RANGE_x / pixels`` (Gwyddion's
convention). Unscanned lines of an aborted scan are NaN in the file and stay NaN.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from arsurf.errors import CorruptScan
from arsurf.scan.readers._common import (
    Channel,
    check_shape,
    flip_rows,
    frombuffer,
    make_scan,
    parse_float,
    parse_int,
    select_channel,
)

MAGIC = b":NANONIS_VERSION:"
EXTENSIONS = (".sxm",)
FORMAT = "sxm"
_TYPES = {"FLOAT": "f4", "INT": "i4", "UINT": "u4", "DOUBLE": "f8"}


def sniff(head: bytes) -> bool:
    """True when the file starts with ``:NANONIS_VERSION:``."""
    return head.lstrip(b"\r\n ").startswith(MAGIC)


def parse_header(path, buf: bytes) -> tuple[dict[str, list[str]], int]:
    """Tag -> list of value lines, and the offset where the data start."""
    end = buf.find(b":SCANIT_END:")
    if end < 0:
        raise CorruptScan(f"{path}: no :SCANIT_END: tag (truncated or not a Nanonis .sxm)")
    marker = buf.find(b"\x1a\x04", end)
    if marker < 0:
        raise CorruptScan(f"{path}: no \\x1a\\x04 data marker after the header (truncated file)")
    text = buf[:end].decode("latin-1")
    header: dict[str, list[str]] = {}
    tag = None
    for line in text.splitlines():
        s = line.strip()
        if len(s) > 2 and s.startswith(":") and s.endswith(":"):
            tag = s[1:-1]
            header[tag] = []
        elif tag is not None and s:
            header[tag].append(line.rstrip("\r\n"))
    return header, marker + 2


def _first(path, header, tag) -> str:
    if not header.get(tag):
        raise CorruptScan(f"{path}: the header has no {tag}")
    return header[tag][0]


def read(path: Path | str, channel: str | None = None):
    """Read one channel of a Nanonis ``.sxm`` file (default: ``Z (forward)``).

    Channel names are ``"<Name> (forward)"`` / ``"<Name> (backward)"``; the bare name selects
    the forward image only when the channel has a single direction.
    """
    buf = Path(path).read_bytes()
    header, start = parse_header(path, buf)
    px = _first(path, header, "SCAN_PIXELS").split()
    rng = _first(path, header, "SCAN_RANGE").split()
    if len(px) < 2 or len(rng) < 2:
        raise CorruptScan(f"{path}: SCAN_PIXELS/SCAN_RANGE need two values (got {px}, {rng})")
    nx, ny = parse_int(path, px[0], "SCAN_PIXELS x"), parse_int(path, px[1], "SCAN_PIXELS y")
    check_shape(path, nx, ny)
    xr, yr = parse_float(path, rng[0], "SCAN_RANGE x"), parse_float(path, rng[1], "SCAN_RANGE y")
    typ = _first(path, header, "SCANIT_TYPE").split()
    if len(typ) != 2 or typ[0] not in _TYPES or typ[1] not in ("MSBFIRST", "LSBFIRST"):
        raise CorruptScan(f"{path}: unsupported SCANIT_TYPE {' '.join(typ)!r}")
    dtype = np.dtype((">" if typ[1] == "MSBFIRST" else "<") + _TYPES[typ[0]])
    rows = header.get("DATA_INFO", [])
    if len(rows) < 2:
        raise CorruptScan(f"{path}: the DATA_INFO table is missing or empty")
    cols = rows[0].split()
    try:
        i_name, i_unit, i_dir = cols.index("Name"), cols.index("Unit"), cols.index("Direction")
    except ValueError:
        raise CorruptScan(f"{path}: DATA_INFO lacks the Name/Unit/Direction columns (got {cols})") from None
    chans: list[Channel] = []
    block = 0
    for row in rows[1:]:
        f = row.split("\t") if "\t" in row.strip() else row.split()
        f = [x.strip() for x in f if x.strip()]
        if len(f) <= max(i_name, i_unit, i_dir):
            raise CorruptScan(f"{path}: DATA_INFO row {row.strip()!r} has too few columns")
        name, unit, d = f[i_name], f[i_unit], f[i_dir].lower()
        dirs = {"both": ("forward", "backward"), "forward": ("forward",), "backward": ("backward",)}.get(d)
        if dirs is None:
            raise CorruptScan(f"{path}: DATA_INFO direction {d!r} of {name!r} is not forward/backward/both")
        for direction in dirs:
            chans.append(Channel(f"{name} ({direction})", key=block, unit=unit, direction=direction))
            block += 1
    npx = nx * ny
    need = start + block * npx * dtype.itemsize
    if len(buf) < need:
        raise CorruptScan(
            f"{path}: {block} images of {nx}x{ny} {dtype} need {need} bytes but the file has {len(buf)} (truncated)"
        )
    chan = select_channel(path, chans, channel)
    img = frombuffer(path, buf, start + chan.key * npx * dtype.itemsize, dtype, npx, chan.name).reshape(ny, nx)
    if chan.direction == "backward":
        img = img[:, ::-1]
    scan_dir = (header.get("SCAN_DIR") or ["down"])[0].strip().lower()
    flipped = scan_dir != "up"
    if flipped:
        img = flip_rows(img)
    info = {
        k: " ".join(v).strip()
        for k, v in header.items()
        if k not in ("DATA_INFO", "Z-CONTROLLER") and len(" ".join(v)) < 400
    }
    return make_scan(
        path, FORMAT, img, xr / nx, yr / ny, chan, chans, rows_flipped=flipped,
        instrument={"software": "Nanonis", "version": info.get("NANONIS_VERSION"),
                    "bias": info.get("BIAS"), "scan_dir": scan_dir, "angle": info.get("SCAN_ANGLE")},
        extra={"header": info},
    )
