"""Nanosurf ``.nid`` reader.

Library: our own parser. Nanosurf's ``NSFopen`` reads the format but needs pandas for its
output, prints progress, uses ``np.float`` (removed in numpy 1.24) in its spectroscopy path
and reads every dataset with the bit depth of the first one; the format is a plain INI-style
header plus integers, so we own it. The layout and scaling follow NSFopen's reader.

Format: a text header of ``[Section]`` blocks with ``Key=Value`` lines. ``[DataSet]`` has
``GroupCount`` and, per group ``g``, ``Gr<g>-Name``, ``Gr<g>-Count`` and ``Gr<g>-Ch<c>`` =
the section of each dataset (``DataSet-0:1``...). A dataset section gives ``Frame`` (``Scan
forward``, ``Scan backward``, ``2nd scan forward``, spectroscopy frames...), ``Points``,
``Lines``, ``SaveBits`` (16 or 32), ``SaveSign``, ``Dim0Min/Range/Unit`` (x),
``Dim1Min/Range/Unit`` (y), ``Dim2Name`` (the channel, e.g. ``Z-Axis``), ``Dim2Unit``,
``Dim2Min``, ``Dim2Range``. After the header comes ``#!`` and the datasets' little-endian
integers one after the other in the order of the groups.

Scaling: a signed raw value ``r`` of ``b`` bits maps to
:math:`z = \\text{Dim2Min} + \\text{Dim2Range}\\,(r + 2^{b-1}) / 2^b` (unsigned: ``r / 2**b``).
Orientation: line ``i`` lies at ``y = Dim1Min + i * Dim1Range / Lines`` (the first stored line
is the bottom of the frame), so rows are kept: row 0 = bottom.
Pixel spacing: ``dx = Dim0Range / Points``, ``dy = Dim1Range / Lines``.
"""
from __future__ import annotations

import math
from pathlib import Path

from arsurf.errors import CorruptScan
from arsurf.scan.readers._common import (
    Channel,
    check_scale,
    check_shape,
    frombuffer,
    make_scan,
    parse_float,
    parse_int,
    parse_unit,
    select_channel,
)

EXTENSIONS = (".nid",)
FORMAT = "nid"
MARKER = b"#!"


def sniff(head: bytes) -> bool:
    """True when the file starts with the ``[DataSet]`` section of a Nanosurf header."""
    return head.lstrip(b"\xef\xbb\xbf\r\n ").startswith(b"[DataSet]")


def parse_header(path, buf: bytes) -> tuple[dict[str, dict[str, str]], int]:
    """Sections as {name: {key: value}} and the offset of the binary data."""
    end = buf.find(MARKER)
    if end < 0:
        raise CorruptScan(f"{path}: no '#!' marker before the data (truncated or not a Nanosurf .nid)")
    text = buf[:end].decode("latin-1")
    sections: dict[str, dict[str, str]] = {}
    current = None
    for line in text.replace("\r", "").split("\n"):
        s = line.strip()
        if s.startswith("[") and s.endswith("]"):
            current = sections.setdefault(s[1:-1], {})
        elif current is not None and "=" in s:
            k, v = s.split("=", 1)
            current.setdefault(k.strip(), v.strip())
    return sections, end + len(MARKER)


def read(path: Path | str, channel: str | None = None):
    """Read one image channel of a ``.nid`` file (default: ``Z-Axis (Scan forward)``).

    Channel names are ``"<Dim2Name> (<Frame>)"``, e.g. ``"Z-Axis (Scan backward)"``.
    """
    buf = Path(path).read_bytes()
    sections, start = parse_header(path, buf)
    ds = sections.get("DataSet")
    if ds is None:
        raise CorruptScan(f"{path}: no [DataSet] section")
    ngroups = parse_int(path, ds.get("GroupCount", ""), "GroupCount")
    if not 0 < ngroups <= 1000:
        raise CorruptScan(f"{path}: GroupCount {ngroups} is not plausible")
    datasets: list[str] = []
    for g in range(ngroups):
        count = parse_int(path, ds.get(f"Gr{g}-Count", "0"), f"Gr{g}-Count")
        if not 0 <= count <= 1000:
            raise CorruptScan(f"{path}: Gr{g}-Count {count} is not plausible")
        for c in range(count):
            key = ds.get(f"Gr{g}-Ch{c}")
            if key:
                datasets.append(key)
    chans: list[Channel] = []
    offset = start
    for key in datasets:
        sec = sections.get(key)
        if sec is None:
            raise CorruptScan(f"{path}: [DataSet] names section [{key}], which is missing")
        nx = parse_int(path, sec.get("Points", ""), f"{key} Points")
        ny = parse_int(path, sec.get("Lines", ""), f"{key} Lines")
        check_shape(path, nx, ny)
        bits = parse_int(path, sec.get("SaveBits", "32"), f"{key} SaveBits")
        if bits not in (16, 32):
            raise CorruptScan(f"{path}: {key} SaveBits must be 16 or 32 (got {bits})")
        frame = sec.get("Frame", key)
        name = sec.get("Dim2Name", key)
        fl = frame.lower()
        if "scan" in fl and "spec" not in fl and "LineDim0Min" not in sec:
            direction = "backward" if "backward" in fl else "forward"
            chans.append(Channel(f"{name} ({frame})", key=(key, offset, nx, ny, bits),
                                 unit=sec.get("Dim2Unit", ""), direction=direction))
        offset += nx * ny * bits // 8
    if offset > len(buf):
        raise CorruptScan(f"{path}: the datasets need {offset} bytes but the file has {len(buf)} (truncated)")
    chan = select_channel(path, chans, channel)
    key, off, nx, ny, bits = chan.key
    sec = sections[key]
    signed = sec.get("SaveSign", "Signed").lower() != "unsigned"
    raw = frombuffer(path, buf, off, ("<i" if signed else "<u") + str(bits // 8), nx * ny, chan.name)
    zmin = parse_float(path, sec.get("Dim2Min", "0"), f"{key} Dim2Min")
    if not math.isfinite(zmin):
        raise CorruptScan(f"{path}: {key} Dim2Min is {zmin!r}; the header is damaged")
    zrange = check_scale(path, parse_float(path, sec.get("Dim2Range", "1"), f"{key} Dim2Range"), f"{key} Dim2Range")
    q = float(2**bits)
    frac = (raw + q / 2) / q if signed else raw / q
    data = (zmin + zrange * frac).reshape(ny, nx)
    fx, bx = parse_unit(sec.get("Dim0Unit", "m"))
    fy, by = parse_unit(sec.get("Dim1Unit", "m"))
    if bx != "m" or by != "m":
        raise CorruptScan(f"{path}: {key} x/y units {sec.get('Dim0Unit')!r}/{sec.get('Dim1Unit')!r} are not lengths")
    xr = parse_float(path, sec.get("Dim0Range", ""), f"{key} Dim0Range") * fx
    yr = parse_float(path, sec.get("Dim1Range", ""), f"{key} Dim1Range") * fy
    info = sections.get("DataSet-Info", {})
    return make_scan(
        path, FORMAT, data, xr / nx, yr / ny, chan, chans, rows_flipped=False,
        instrument={"software": "Nanosurf", **{k.strip(" :"): v for k, v in list(info.items())[:60]}},
        extra={"dataset": key, "save_bits": bits},
    )
