r"""Park Systems (PSIA) TIFF reader (``.tiff``/``.tif`` from SmartScan/XEI).

Library: ``tifffile`` for the TIFF directory; the Park layer is ours (no maintained Python
package reads it; the 8-bit image in the TIFF is only a colour preview). Field layout after
Gwyddion's ``psia.c`` and SOURCES.md.

Private tags: 50432 magic ``0x0E031301``, 50433 version, 50434 the data, 50435 a
little-endian header: image type (u32) at 0 (0 = 2-D image; 1 line profile and 2 spectroscopy
are not images), source name (UTF-16, 32 chars) at 4, image mode (UTF-16, 8) at 68, width at
100 and height at 104 (u32), forward flag at 128, scan-up flag at 132, x/y scan size in um at
140/148 (f64), x/y offset in um at 156/164, data gain at 220, z scale at 228, z offset at 236
(f64), z unit (UTF-16, 8) at 244 and, from header version 2 (tag 50433 = ``0x01000002``), the
data type (u32) at 348: 0 int16, 1 int32, 2 float32 (Park's header layout as read by
nanoAFMr's ``get.ParkAFM.header`` and AtomicJ's ``ParkHeader2``). Version 1 headers (Gwyddion's
``psia.c``) store int16 only.

Data: ``width x height`` values of that type, exactly filling tag 50434 (any other byte count
is refused: a wrong width or type would otherwise read floats as integers, the +-0.15 m
"heights" of a misread), scaled as Gwyddion and AtomicJ do for every type:

.. math:: z = \text{gain}\,(\text{raw}\,z_\text{scale} + z_\text{offset})

in the z unit, with a z scale of 0 read as 1 (Gwyddion). The gain can be negative (-4.509 on
the real file, whose z scale is 1 and offset 0) and is kept as is; it must be finite and
non-zero (:func:`arsurf.scan.readers._common.check_scale`).

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
    check_data_size,
    check_scale,
    check_shape,
    check_tiff_chain,
    make_scan,
    quiet_logger,
    select_channel,
    tiff_first_ifd_tags,
)

EXTENSIONS = (".tiff", ".tif")
FORMAT = "park-tiff"
MAGIC_NUMBER = 0x0E031301
#: Park header data type (byte 348 of a version 2 header) -> stored little-endian values
_DATA_TYPES = {0: "<i2", 1: "<i4", 2: "<f4"}
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
    version_2 = isinstance(version, (int, np.integer)) and (int(version) & 0xFF) >= 2
    need = 352 if version_2 else 260
    if len(header) < need:
        raise CorruptScan(f"{path}: the Park header is {len(header)} bytes; version {version!r} needs at least {need}")
    (image_type,) = struct.unpack_from("<I", header, 0)
    if image_type != 0:
        raise CorruptScan(f"{path}: the Park image type is {image_type} (1 = line profile, 2 = spectroscopy), "
                          "not a 2-D image")
    nx, ny = struct.unpack_from("<II", header, 100)
    check_shape(path, int(nx), int(ny))
    forward, scan_up = struct.unpack_from("<II", header, 128)
    xs, ys = struct.unpack_from("<dd", header, 140)
    gain, zscale, zoff = struct.unpack_from("<ddd", header, 220)
    (data_type,) = struct.unpack_from("<I", header, 348) if version_2 else (0,)
    if data_type not in _DATA_TYPES:
        raise CorruptScan(f"{path}: the Park data type is {data_type}; the format defines 0 (int16), 1 (int32) "
                          "and 2 (float32)")
    dtype = np.dtype(_DATA_TYPES[data_type])
    check_data_size(path, len(payload), nx * ny * dtype.itemsize,
                    f"{nx} x {ny} {dtype.name} pixels (Park data tag 50434)", exact=True)
    gain = check_scale(path, gain, "the Park data gain")
    zscale = 1.0 if zscale == 0.0 else check_scale(path, zscale, "the Park z scale")
    if not np.isfinite(zoff):
        raise CorruptScan(f"{path}: the Park z offset is {zoff!r}; the header is damaged")
    z_unit = _utf16(header, 244, 8) or "um"
    source, mode = _utf16(header, 4, 32) or "Height", _utf16(header, 68, 8)
    raw = np.frombuffer(payload, dtype=dtype, count=nx * ny).astype(np.float64)
    with np.errstate(invalid="ignore", over="ignore"):  # damaged floats: counted by make_scan
        data = gain * (raw * zscale + zoff)
    chan = Channel(source, key=0, unit=z_unit, direction="forward" if forward else "backward")
    chan = select_channel(path, [chan], channel)
    return make_scan(
        path, FORMAT, data.reshape(ny, nx), xs * 1e-6 / nx, ys * 1e-6 / ny, chan, [chan], rows_flipped=False,
        instrument={"software": "Park Systems", "mode": mode, "version": version, "scan_up": bool(scan_up)},
        extra={"data_gain": gain, "z_scale": zscale, "z_offset": zoff, "data_type": dtype.name},
    )
