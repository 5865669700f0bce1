"""Park Systems (PSIA) TIFF reader (``.tiff``/``.tif`` from SmartScan/XEI).

Library: ``tifffile`` for the TIFF directory; the Park layer is ours (no maintained Python
package reads it; the 8-bit image in the TIFF is only a colour preview). Field layout after
Gwyddion's ``psia.c`` and SOURCES.md.

Private tags: 50432 magic ``0x0E031301``, 50433 version, 50434 the data, 50435 a
little-endian header: image type (u32) at 0, source name (UTF-16, 32 chars) at 4, image mode
(UTF-16, 8) at 68, width at 100 and height at 104 (u32), forward flag at 128, scan-up flag at
132, x/y scan size in um at 140/148 (f64), x/y offset in um at 156/164, data gain at 220,
z scale at 228, z offset at 236 (f64), z unit (UTF-16, 8) at 244.
Data: float32 when the data tag has 4 bytes per pixel (``height = data * gain`` in the z
unit); 16-bit data (older files) give ``height = (data * z_scale + z_offset) * gain``.
The gain can be negative (-4.509 on the real file) and must be kept as is.

Orientation: the first stored line is the bottom of the image (Gwyddion writes it to its last
row), so rows are kept: row 0 = bottom. Pixel spacing ``dx = x scan size / width``.
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from arsurf.errors import CorruptScan, require
from arsurf.scan.readers._common import (
    Channel,
    check_shape,
    check_tiff_chain,
    make_scan,
    quiet_logger,
    parse_unit,
    select_channel,
    tiff_first_ifd_tags,
)

EXTENSIONS = (".tiff", ".tif")
FORMAT = "park-tiff"
MAGIC_NUMBER = 0x0E031301
TAG_MAGIC, TAG_VERSION, TAG_DATA, TAG_HEADER = 50432, 50433, 50434, 50435


def sniff(head: bytes) -> bool:
    """True for a TIFF whose first directory has the Park magic tag 50432 = 0x0E031301."""
    tags = tiff_first_ifd_tags(head)
    if TAG_MAGIC not in tags:
        return False
    _, _, value = tags[TAG_MAGIC]
    bo = "<" if head[:2] == b"II" else ">"
    return struct.unpack(bo + "I", value)[0] == MAGIC_NUMBER


def _utf16(raw: bytes, offset: int, nchar: int) -> str:
    return raw[offset : offset + 2 * nchar].decode("utf-16-le", errors="replace").split("\x00")[0].strip()


def _as_bytes(value) -> bytes:
    if isinstance(value, (bytes, bytearray)):
        return bytes(value)
    if isinstance(value, np.ndarray):
        return value.tobytes()
    if isinstance(value, (tuple, list)):
        return bytes(int(v) & 0xFF for v in value)
    raise TypeError(type(value))


def read(path: Path | str, channel: str | None = None):
    """Read the height image of a Park Systems TIFF (one channel per file)."""
    tifffile = require("tifffile", "formats", "reading Park Systems TIFF files")
    check_tiff_chain(path, path)
    with quiet_logger("tifffile"), tifffile.TiffFile(str(path)) as tif:
        tags = tif.pages[0].tags
        magic = tags.get(TAG_MAGIC)
        if magic is None or magic.value != MAGIC_NUMBER:
            raise CorruptScan(f"{path}: not a Park Systems TIFF (tag 50432 is missing or not 0x0E031301)")
        if tags.get(TAG_HEADER) is None or tags.get(TAG_DATA) is None:
            raise CorruptScan(f"{path}: the Park header (tag 50435) or data (tag 50434) is missing")
        header = _as_bytes(tags[TAG_HEADER].value)
        payload = _as_bytes(tags[TAG_DATA].value)
        version = tags.get(TAG_VERSION).value if tags.get(TAG_VERSION) is not None else None
    if len(header) < 260:
        raise CorruptScan(f"{path}: the Park header is {len(header)} bytes; at least 260 are needed")
    nx, ny = struct.unpack_from("<II", header, 100)
    check_shape(path, int(nx), int(ny))
    forward, scan_up = struct.unpack_from("<II", header, 128)
    xs, ys = struct.unpack_from("<dd", header, 140)
    gain, zscale, zoff = struct.unpack_from("<ddd", header, 220)
    z_unit = _utf16(header, 244, 8) or "um"
    source, mode = _utf16(header, 4, 32) or "Height", _utf16(header, 68, 8)
    bpp = len(payload) // (nx * ny)
    if bpp == 4:
        data = np.frombuffer(payload, dtype="<f4", count=nx * ny).astype(np.float64) * gain
    elif bpp == 2:
        raw = np.frombuffer(payload, dtype="<i2", count=nx * ny).astype(np.float64)
        data = (raw * (zscale or 1.0) + zoff) * gain
    else:
        raise CorruptScan(
            f"{path}: the Park data tag holds {len(payload)} bytes for {nx}x{ny} pixels (truncated or corrupt)"
        )
    f_z, base = parse_unit(z_unit)
    chan = Channel(source, key=0, unit=z_unit, direction="forward" if forward else "backward")
    chan = select_channel(path, [chan], channel)
    return make_scan(
        path, FORMAT, data.reshape(ny, nx), xs * 1e-6 / nx, ys * 1e-6 / ny, chan, [chan], rows_flipped=False,
        instrument={"software": "Park Systems", "mode": mode, "version": version, "scan_up": bool(scan_up)},
        extra={"data_gain": gain, "bytes_per_pixel": bpp},
    )
