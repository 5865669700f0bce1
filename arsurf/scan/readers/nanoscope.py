"""Bruker/Veeco NanoScope (``.spm``, ``.000``-``.999``) reader.

Library: our own parser. ``pySPM.Bruker`` 0.6.3 gets the Z scale of 16-bit images right, but
its header loop (``while True: readline()`` until ``*File list end``) never ends on a
truncated or damaged file, it ignores ``Bytes/pixel`` when naming the integer type of the
offset, it rescales the y size by ``lines/samples`` even when ``Scan size`` gives both sizes,
and importing it takes about 3 s (matplotlib). Our reader agrees with it on the real file
(checked in the tests).

Format: a text header of ``\\key: value`` lines grouped in ``\\*Section`` lists, ending with
``\\*File list end``; each ``\\*Ciao image list`` section describes one image (``Data offset``,
``Data length``, ``Bytes/pixel``, ``Samps/line``, ``Number of lines``, ``Scan size``,
``Line direction``, ``@2:Image Data``, ``@2:Z scale``); the data are little-endian signed
integers.

Z scale (the known trap). A line such as
``\\@2:Z scale: V [Sens. Zscan] (0.006539403 V/LSB) 41.60368 V`` holds a *hard scale*
(0.006539403 V/LSB, the resolution of the 16-bit Z DAC: 65536 x 0.006539 V = 428.57 V = the
``Z limit``) and a *hard value* (41.60368 V, the voltage that the full range of the stored
integers spans). The soft scale comes from the ``\\@Sens. Zscan: V 7.000000 nm/V`` line named
in the brackets. The height is

.. math:: z = \\frac{\\text{raw}}{2^{8\\,\\text{bpp}}}\\;V_\\text{hard value}\\;S_\\text{soft}

(here 41.60368 V / 65536 x 7 nm/V = 4.444e-3 nm per LSB). Multiplying the raw integers by the
hard scale instead (0.006539 V/LSB x 7 nm/V) overstates every height by 428.57/41.60 = 10.3:
on the Veeco file that gives 1643 nm peak-to-peak instead of the 159.5 nm of SOURCES.md.
Channels without a bracketed sensitivity (phase, amplitude) are in the hard value's unit.
The ``Z offset`` line is not applied (as Gwyddion).

Orientation: the first stored line is the bottom of the image (NanoScope scans and stores from
the bottom up; Gwyddion flips it for display), so rows are kept as stored: row 0 = bottom.
Pixel spacing: ``dx = scan size x / Samps/line``, ``dy = scan size y / Number of lines``.
"""
from __future__ import annotations

import re
from pathlib import Path

from arsurf.errors import CorruptScan
from arsurf.scan.readers._common import (
    Channel,
    check_shape,
    frombuffer,
    make_scan,
    parse_float,
    parse_int,
    parse_unit,
    select_channel,
)

EXTENSIONS = (".spm",) + tuple(f".{i:03d}" for i in range(1000))
FORMAT = "nanoscope"
_MAGICS = (b"\\*File list", b"\\*EC File list", b"?*File list", b"\\*Force file list")
_END = b"\\*File list end"
_ZSCALE = re.compile(
    r"^\s*\w*\s*(?:\[(?P<sens>[^\]]*)\])?\s*(?:\((?P<hard>(?:[^()]|\([^()]*\))*)\))?\s*"
    r"(?P<value>[-+]?[\d.]+(?:[eE][-+]?\d+)?)\s*(?P<unit>\S*)"
)


def sniff(head: bytes) -> bool:
    """True when the file starts with a NanoScope ``\\*File list`` header."""
    return head.startswith(_MAGICS)


def parse_header(path, buf: bytes) -> list[tuple[str, dict[str, str]]]:
    """The header as a list of (section name, {key: value}), keys lower-cased (NanoScope matches
    header keys without regard to case: v5 writes ``Scan size``, v7-v10 ``Scan Size``)."""
    end = buf.find(_END)
    if end < 0:
        raise CorruptScan(f"{path}: no '\\*File list end' line (truncated or not a NanoScope file)")
    text = buf[:end].decode("latin-1")
    sections: list[tuple[str, dict[str, str]]] = []
    for line in text.replace("\r", "").split("\n"):
        if not line.startswith("\\"):
            continue
        line = line[1:]
        if line.startswith("*"):
            sections.append((line[1:].strip(), {}))
            continue
        if not sections:
            continue
        # keys can hold a colon themselves ("@2:Z scale"); the separator is ": "
        key, sep, value = line.partition(": ") if ": " in line else line.partition(":")
        if sep:  # keys are matched as the format does: without regard to case (v9 writes "Scan Size")
            sections[-1][1].setdefault(key.strip().lower(), value.strip())
    return sections


def _lookup(sections, key: str) -> str | None:
    key = key.lower()
    for _, d in sections:
        if key in d:
            return d[key]
    return None


def _soft_scale(path, sections, sens: str) -> tuple[float, str]:
    """SI units per volt of ``@<sens>`` (e.g. ``V 7.000000 nm/V`` -> (7e-9, 'm'))."""
    text = _lookup(sections, "@" + sens)
    if text is None:
        raise CorruptScan(f"{path}: the Z scale refers to [{sens}] but the header has no '@{sens}' line")
    m = re.match(r"^\s*\w*\s*([-+]?[\d.]+(?:[eE][-+]?\d+)?)\s*(\S*)", text)
    if not m:
        raise CorruptScan(f"{path}: cannot read the sensitivity '@{sens}: {text}'")
    value = parse_float(path, m.group(1), "@" + sens)
    unit = m.group(2)
    num = unit.split("/")[0] if "/" in unit else unit
    factor, base = parse_unit(num)
    return value * factor, base


def _image_name(d: dict[str, str], i: int) -> str:
    for key in ("@2:image data", "@3:image data", "image data"):
        if key in d:
            v = d[key]
            m = re.search(r'"([^"]*)"', v) or re.search(r"\[([^\]]*)\]", v)
            if m and m.group(1):
                return m.group(1)
    return f"Image {i}"


def read(path: Path | str, channel: str | None = None):
    """Read one image of a NanoScope file (default: the Height Sensor channel when recorded,
    else the first trace, else retrace, height).

    Channel names are ``"<Image Data name> (Trace)"`` or ``"(Retrace)"``, e.g.
    ``"Height (Retrace)"``; the bare ``"Height"`` works when it is unique.
    """
    buf = Path(path).read_bytes()
    sections = parse_header(path, buf)
    images = [d for name, d in sections if name.lower() in ("ciao image list", "afm image list", "stm image list")]
    if not images:
        raise CorruptScan(f"{path}: the header lists no image (no '\\*Ciao image list' section)")
    chans: list[Channel] = []
    for i, d in enumerate(images):
        name = _image_name(d, i)
        line_dir = d.get("line direction", "").strip()
        direction = {"trace": "forward", "retrace": "backward"}.get(line_dir.lower())
        label = f"{name} ({line_dir})" if line_dir else name
        zline = d.get("@2:z scale", "")
        unit = "m" if "[" in zline and re.search(r"height|topo|z ?sensor", name, re.I) else "V"
        chans.append(Channel(label, key=i, unit=unit, direction=direction))
    if channel is None:  # the default is the height: the Height Sensor when recorded, as Bruker's software does
        sensor = [c for c in chans if c.name.lower().startswith(("height sensor", "zsensor"))]
        sensor.sort(key=lambda c: c.direction != "forward")
        chan = sensor[0] if sensor else select_channel(path, chans, None)
    else:
        chan = select_channel(path, chans, channel)
    d = images[chan.key]
    nx = parse_int(path, d.get("samps/line", ""), "Samps/line")
    ny = parse_int(path, d.get("number of lines", ""), "Number of lines")
    check_shape(path, nx, ny)
    bpp = parse_int(path, d.get("bytes/pixel", "2"), "Bytes/pixel")
    if bpp not in (2, 4):
        raise CorruptScan(f"{path}: Bytes/pixel must be 2 or 4 (got {bpp})")
    offset = parse_int(path, d.get("data offset", ""), "Data offset")
    length = parse_int(path, d.get("data length", str(nx * ny * bpp)), "Data length")
    # v9+ files store every image as 4-byte integers while some lists still say "Bytes/pixel: 2":
    # the data length says how wide the stored integers are; the Z scale still counts in units
    # of 2^(8 Bytes/pixel) (as pySPM reads them: Height of sample_0.spm 21.2-37.1 nm)
    width = 4 if (length == nx * ny * 4 and bpp == 2) else bpp
    if length < nx * ny * width:
        raise CorruptScan(f"{path}: Data length {length} is less than {nx}x{ny}x{width} bytes")
    raw = frombuffer(path, buf, offset, f"<i{width}", nx * ny, f"image {chan.name!r}").reshape(ny, nx)

    # lateral size: "Scan size: 1.76908 1.76908 ~m" (image list) or "Scan size: 1769.08 nm"
    size = d.get("scan size") or _lookup(sections, "Scan size") or ""
    parts = size.split()
    try:
        if len(parts) >= 3:
            f, base = parse_unit(parts[2])
            xs, ys = float(parts[0]) * f, float(parts[1]) * f
        elif len(parts) == 2:
            f, base = parse_unit(parts[1])
            xs = float(parts[0]) * f
            a, b = (d.get("aspect ratio") or _lookup(sections, "Aspect ratio") or "1:1").split(":")
            ys = xs * float(b) / float(a)
        else:
            raise ValueError(size)
    except (ValueError, ZeroDivisionError):
        raise CorruptScan(f"{path}: cannot read the scan size {size!r}") from None
    if base != "m":
        raise CorruptScan(f"{path}: scan size unit in {size!r} is not a length")

    zline = d.get("@2:z scale")
    if zline is None:
        raise CorruptScan(f"{path}: image {chan.name!r} has no '@2:Z scale' line")
    m = _ZSCALE.match(zline)
    if not m:
        raise CorruptScan(f"{path}: cannot read '@2:Z scale: {zline}'")
    hard_value = parse_float(path, m.group("value"), "the Z scale hard value")
    hv_factor, hv_unit = parse_unit(m.group("unit") or "V")
    volts = hard_value * hv_factor / float(2 ** (8 * bpp))  # hard-value units per LSB
    if m.group("sens"):
        soft, z_unit = _soft_scale(path, sections, m.group("sens").strip())
        z_factor = volts * soft
    else:
        z_factor, z_unit = volts, hv_unit
    chan.unit = z_unit
    version = _lookup(sections, "Version")
    return make_scan(
        path, FORMAT, raw, xs / nx, ys / ny, chan, chans, rows_flipped=False,
        z_factor=z_factor, z_unit=z_unit,
        instrument={
            "software": "NanoScope", "version": version,
            "description": _lookup(sections, "Description"), "microscope": _lookup(sections, "Microscope"),
            "date": _lookup(sections, "Date"),
        },
        extra={"z_scale_line": zline, "z_per_lsb": z_factor, "bytes_per_pixel": bpp, "stored_bytes_per_pixel": width,
               "line_direction": d.get("line direction"), "frame_direction": d.get("frame direction")},
    )
