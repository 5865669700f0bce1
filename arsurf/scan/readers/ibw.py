"""Asylum Research / Igor Pro binary wave (``.ibw``) reader.

Library: ``igor2`` (``igor2.binarywave.load``), the maintained fork of ``igor``; it parses the
binary header, the wave header, the note and the dimension labels correctly, and the format
has enough versions (1, 2, 3, 5; both byte orders) that owning it is not worth it. We add the
Asylum conventions on top: channel names from the layer labels, the pixel spacing from the
wave scaling and the axis order. Its exceptions on damaged files (``struct.error``,
``ValueError``...) are turned into :class:`arsurf.errors.CorruptScan` by the loader.

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


def _checksum_ok(head: bytes, order: str, n: int) -> bool:
    if len(head) < n:
        return False
    words = struct.unpack(f"{order}{n // 2}h", head[:n])
    return (sum(words) & 0xFFFF) == 0


def sniff(head: bytes) -> bool:
    """True for an Igor binary wave: version 2, 3 or 5 in either byte order and a valid header checksum."""
    if len(head) < 8:
        return False
    for order in ("<", ">"):
        (version,) = struct.unpack(order + "h", head[:2])
        if version == 5 and _checksum_ok(head, order, 384):
            return True
        if version in (2, 3) and _checksum_ok(head, order, 126):
            return True
    return False


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
    bw = require("igor2.binarywave", "formats", "reading Igor/Asylum .ibw files")
    with quiet_logger("igor2"):
        wave = bw.load(str(path))["wave"]
    wh = wave["wave_header"]
    data = np.asarray(wave["wData"])
    if data.ndim not in (2, 3):
        raise CorruptScan(f"{path}: the wave has {data.ndim} dimensions; an image needs 2 or 3")
    if data.ndim == 2:
        data = data[:, :, None]
    nx, ny, nlayers = data.shape
    check_shape(path, int(nx), int(ny))
    labels = wave.get("labels") or []
    layer_labels = []
    if len(labels) > 2 and labels[2]:
        layer_labels = [_text(x) for x in labels[2][1:]]
    names = []
    for i in range(nlayers):
        name = layer_labels[i] if i < len(layer_labels) and layer_labels[i] else f"Layer {i}"
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
