"""Asylum Research / Igor Pro binary wave (``.ibw``) reader.

Library: ``igor2`` (``igor2.binarywave``), the maintained fork of ``igor``; it parses the
binary header, the wave header, the data and the note correctly, and the format
has enough versions (1, 2, 3, 5; both byte orders) that owning it is not worth it. We add the
Asylum conventions on top: channel names from the layer labels, the pixel spacing from the
wave scaling and the axis order. Its exceptions on damaged files (``struct.error``,
``ValueError``...) are turned into :class:`arsurf.errors.CorruptScan` by the loader.

igor2 sizes its reads and allocations by the header's fields unchecked (a ``dimLabelsSize`` of
2**31 makes it allocate ~9 GB) and keeps its parser in a thread-local object whose state such a
failure leaves broken for every later read in the process. So the whole header is validated
first (:func:`check_header`, WaveMetrics Technical Note 003 and its ``ReadWave.c``): the
version (an image needs version 5: versions 1-3 hold one-dimensional waves only), the checksum
(the 16-bit sum of the first 380 bytes of a version 5 file is 0), every section size >= 0 and
their sum within the file, a numeric data type, ``nDim`` consistent with ``npnts`` and with the
data section's size. Only then does igor2 read the file, with a parser built for this read
(``setup_wave``), never the shared one.

Layer names are read from the file's bytes, not from igor2: TN003 stores each dimension label
as a NUL-terminated string in a 32-byte field (``dimLabelsSize[d] = 32 (nDim[d] + 1)``, the
first field naming the dimension as a whole), and igor2 joins the fields' characters dropping
the NULs, so a label padded with old text (``PhaseRetrace\0race``, as Asylum writes them) came
out as ``PhaseRetracerace``. Each field is cut at its first NUL (:func:`_text`).

Axis order: Asylum stores ``wData[x, y, channel]`` (Igor's first dimension is the row of the
wave, which Asylum uses for x), so each layer is transposed to ``heights[iy, ix]``.
Orientation: Igor's y axis points up (y index 0 at the bottom), so after the transpose row 0
is the bottom: no flip.
Pixel spacing: the wave scaling ``sfA`` (delta per point) is used as is. For Asylum images it
equals ``ScanSize / (N - 1)`` (4 um / 127 = 31.496 nm on the real file), i.e. the scan size
spans first to last pixel centre, unlike Gwyddion's ``xreal / N``.
Units: ``dataUnits`` is one unit for all layers; Asylum writes ``m`` and the height layers
(Height, ZSensor) are in metres; other layers (Amplitude in m, Phase in degrees, Deflection in
m or V) are returned with that unit as written.
"""
from __future__ import annotations

import io
import struct
from pathlib import Path

import numpy as np

from arsurf.errors import CorruptScan, require
from arsurf.scan.readers._common import (
    Channel,
    check_shape,
    direction_from_name,
    make_scan,
    quiet_logger,
    parse_unit,
    select_channel,
)

EXTENSIONS = (".ibw",)
FORMAT = "ibw"


#: bytes covered by the header checksum per version (ReadWave.c: binary header + wave header;
#: version 5 leaves out the 4-byte wData field): 8 + 126, 16 + 126, 20 + 126, 64 + 320 - 4
CHECKSUM_BYTES = {1: 134, 2: 142, 3: 146, 5: 380}
#: Igor numeric wave types (TN003 ``type``): NT_CMPLX = 1 may be or-ed with a real type;
#: NT_UNSIGNED = 0x40 with an integer type; 0 is a text wave
_REAL_TYPES = {2: 4, 4: 8, 8: 1, 0x10: 2, 0x20: 4, 0x48: 1, 0x50: 2, 0x60: 4}


def _checksum_ok(head: bytes, order: str, n: int) -> bool:
    if len(head) < n:
        return False
    words = struct.unpack(f"{order}{n // 2}h", head[:n])
    return (sum(words) & 0xFFFF) == 0


def _version(head: bytes) -> tuple[int, str] | None:
    """(version, byte order) of an Igor binary wave: the version's low byte is non-zero in the
    writer's byte order (ReadWave.c's ``needToReorderBytes``)."""
    if len(head) < 2:
        return None
    for order in ("<", ">"):
        (version,) = struct.unpack(order + "h", head[:2])
        if version in CHECKSUM_BYTES:
            return version, order
    return None


def sniff(head: bytes) -> bool:
    """True for an Igor binary wave: version 1, 2, 3 or 5 in either byte order and a valid header checksum."""
    found = _version(head)
    return found is not None and _checksum_ok(head, found[1], CHECKSUM_BYTES[found[0]])


def check_header(path, buf: bytes) -> dict:
    """Validate a version 5 binary wave against TN003 before any parser sizes a read from it.

    Returns the fields used (``order``, ``npnts``, ``type``, ``nDim``, section sizes).

    Raises
    ------
    CorruptScan
        Naming the field: not an Igor wave, a version other than 5 (one-dimensional), a bad
        checksum, a negative or oversized section, a text or unknown data type, ``nDim`` that
        disagree with ``npnts`` or with the data section.
    """
    found = _version(buf)
    if found is None:
        raise CorruptScan(f"{path}: not an Igor binary wave (the version field is not 1, 2, 3 or 5)")
    version, order = found
    if version != 5:
        raise CorruptScan(f"{path}: Igor binary wave version {version} holds a one-dimensional wave only; an "
                          "image (rows x columns x layers) needs version 5 (Igor Pro 3 and later)")
    if len(buf) < 384:
        raise CorruptScan(f"{path}: {len(buf)} bytes cannot hold the 384-byte headers of an Igor wave (truncated)")
    if not _checksum_ok(buf, order, CHECKSUM_BYTES[5]):
        raise CorruptScan(f"{path}: the Igor header checksum is wrong (the first 380 bytes must sum to 0): the "
                          "header is damaged")
    wfm, formula, note, data_units = struct.unpack_from(order + "4l", buf, 4)
    dim_units = struct.unpack_from(order + "4l", buf, 20)
    dim_labels = struct.unpack_from(order + "4l", buf, 36)
    (s_indices,) = struct.unpack_from(order + "l", buf, 52)
    sizes = {"wfmSize": wfm, "formulaSize": formula, "noteSize": note, "dataEUnitsSize": data_units,
             **{f"dimEUnitsSize[{i}]": v for i, v in enumerate(dim_units)},
             **{f"dimLabelsSize[{i}]": v for i, v in enumerate(dim_labels)}, "sIndicesSize": s_indices}
    for key, value in sizes.items():
        if value < 0:
            raise CorruptScan(f"{path}: the Igor header field {key} is {value}; section sizes cannot be negative")
    total = 64 + sum(sizes.values())
    if total > len(buf):
        big = max(sizes, key=sizes.get)
        raise CorruptScan(f"{path}: the Igor header's sections need {total} bytes but the file has {len(buf)} "
                          f"(largest: {big} = {sizes[big]}); the header is damaged or the file truncated")
    w = 64  # WaveHeader5
    (npnts,) = struct.unpack_from(order + "l", buf, w + 12)
    (wtype,) = struct.unpack_from(order + "h", buf, w + 16)
    ndim = struct.unpack_from(order + "4l", buf, w + 68)
    real = wtype & ~1
    if wtype == 0 or real not in _REAL_TYPES:
        raise CorruptScan(f"{path}: Igor wave type {wtype:#x} is not a numeric image (text wave or unknown type)")
    itemsize = _REAL_TYPES[real] * (2 if wtype & 1 else 1)
    dims = [n for n in ndim if n > 0]
    if any(n < 0 for n in ndim) or not dims or int(np.prod(dims, dtype=np.int64)) != npnts:
        raise CorruptScan(f"{path}: the Igor wave's nDim {list(ndim)} do not multiply to its npnts = {npnts}")
    if wfm - 320 != npnts * itemsize:
        raise CorruptScan(f"{path}: the Igor wave holds {npnts} values of {itemsize} bytes = {npnts * itemsize} "
                          f"bytes, but its wfmSize gives {wfm - 320} bytes of data")
    labels_at = 64 + wfm + formula + note + data_units + sum(dim_units)
    return {"order": order, "npnts": npnts, "type": wtype, "nDim": ndim, "sizes": sizes,
            "labels_at": labels_at, "dim_labels": dim_labels}


def layer_labels(buf: bytes, header: dict) -> list[str] | None:
    """The labels of the layers (dimension 2) from the file's 32-byte label fields, each cut at
    its first NUL; None when the file has no labels for that dimension in that layout."""
    size = header["dim_labels"][2]
    if size < 64 or size % 32:
        return None
    start = header["labels_at"] + sum(header["dim_labels"][:2])
    return [_text(buf[start + 32 * k : start + 32 * (k + 1)]) for k in range(1, size // 32)]


def _load_isolated(path, buf: bytes) -> dict:
    """``igor2``'s reading of ``buf`` with a parser built for this call: its shared thread-local
    parser keeps the state of a failed read and would break the next one."""
    bw = require("igor2.binarywave", "formats", "reading Igor/Asylum .ibw files")
    with quiet_logger("igor2"):
        setup = getattr(bw, "setup_wave", None)
        if setup is None:  # older igor2: only the module-level loader exists
            return bw.load(io.BytesIO(buf))
        return setup(byte_order="=").unpack_stream(io.BytesIO(buf))


def _text(value) -> str:
    """A label as text, cut at the first NUL (Igor pads labels and leaves old text after the NUL:
    ``PhaseRetrace\\0race`` is ``PhaseRetrace``)."""
    if isinstance(value, np.ndarray):  # raw bytes: an S1 item holding NUL reads as b"" (the NUL is lost)
        value = np.ascontiguousarray(value).tobytes()
    if isinstance(value, bytes):
        return value.split(b"\0", 1)[0].decode("latin-1", errors="replace")
    return str(value or "").split("\0", 1)[0]


def _note(raw: bytes | str) -> dict[str, str]:
    text = _text(raw)
    out: dict[str, str] = {}
    for line in text.replace("\n", "\r").split("\r"):
        key, sep, value = line.partition(":")
        if sep and key.strip() and len(out) < 2000:
            out.setdefault(key.strip(), value.strip())
    return out


def read(path: Path | str, channel: str | None = None):
    """Read one layer of an Asylum ``.ibw`` image (default: the first trace, else retrace, height).

    Examples
    --------
    >>> scan = read("AR_20211011.ibw", channel="ZSensorRetrace")  # doctest: +SKIP
    """
    buf = Path(path).read_bytes()
    header = check_header(path, buf)
    wave = _load_isolated(path, buf)["wave"]
    wh = wave["wave_header"]
    data = np.asarray(wave["wData"])
    if data.ndim not in (2, 3):
        raise CorruptScan(f"{path}: the wave has {data.ndim} dimensions; an image needs 2 or 3")
    if data.ndim == 2:
        data = data[:, :, None]
    nx, ny, nlayers = data.shape
    check_shape(path, int(nx), int(ny))
    labels = layer_labels(buf, header) or []
    names = []
    for i in range(nlayers):
        name = labels[i] if i < len(labels) and labels[i] else f"Layer {i}"
        names.append(name if name not in names else f"{name} [{i}]")
    data_unit = _text(wh.get("dataUnits", b""))
    dim_units = wh.get("dimUnits")
    xy_unit = _text(dim_units[0]) if dim_units is not None and len(dim_units) else "m"
    chans = [
        Channel(n, key=i, unit=data_unit if ("phase" not in n.lower()) else "deg", direction=direction_from_name(n))
        for i, n in enumerate(names)
    ]
    chan = select_channel(path, chans, channel)
    sfa = np.asarray(wh.get("sfA", [1.0, 1.0]), dtype=np.float64)
    f_xy, base = parse_unit(xy_unit or "m")
    if base != "m":
        raise CorruptScan(f"{path}: the x/y dimension unit {xy_unit!r} is not a length")
    dx, dy = abs(float(sfa[0])) * f_xy, abs(float(sfa[1])) * f_xy
    img = np.ascontiguousarray(data[:, :, chan.key].T)
    note = _note(wave.get("note", b""))
    keep = ("ScanSize", "FastScanSize", "SlowScanSize", "ScanRate", "ImagingMode", "SpringConstant",
            "InvOLS", "ScanAngle", "Date", "Time", "MicroscopeModel", "Version", "ImageNote")
    return make_scan(
        path, FORMAT, img, dx, dy, chan, chans, rows_flipped=False,
        instrument={"software": "Asylum Research / Igor Pro", **{k: note[k] for k in keep if k in note}},
        extra={"wave_name": _text(wh.get("bname", b"")), "sfA": sfa[:2].tolist(), "axis_order": "[x, y, channel] transposed"},
    )
