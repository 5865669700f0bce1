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

Units of the other channels (PeakForce QNM: DMTModulus, Adhesion, Deformation, Dissipation...).
The same rule holds for every image: the value is hard value x soft value, and its unit is what
is left when the soft scale's denominator cancels the hard value's unit (:func:`resolve_unit`):
``[Sens. ForceSens] ... 4096 Arb`` with ``\\@Sens. ForceSens: V 0.006 V/Arb`` gives volts of
cantilever deflection, ``Pa/Arb`` gives pascals, ``nN/Arb`` newtons, ``eV/Arb`` joules. A
sensitivity written without a unit (``\\@Sens. StiffnessSens: V 1.000000``, what NanoScope writes
when the cantilever is not calibrated) leaves the hard unit, often ``Arb``: the channel is then
returned in ``Arb`` and flagged ``metadata["calibrated"] = False``; we never guess a unit the file
does not state. A ``log(...)`` unit (``LogDMTModulus``: ``log(Arb)``, ``log(Pa)/log(Arb)``) holds
the base-10 logarithm of the quantity (checked on the real v9.3 file: LogDMTModulus =
log10 DMTModulus pixel by pixel); such a channel is returned decoded, ``10**value`` in the
inner unit, with ``metadata["log10_decoded"] = True`` and ``file_z_unit = "log(<unit>)"``.
Sources: Gwyddion ``modules/file/nanoscope.c`` (``get_physical_scale``: hard value x soft
value, LSB = 2^(8 Bytes/pixel) via ``get_bpp_and_qbpp``, v9.2+ data stored as 32-bit), which we
follow except that a unitless soft scale keeps the hard unit where Gwyddion writes ``V``;
pySPM ``Bruker.get_channel`` (same numbers, checked in the tests); the NanoScope 8.10 User
Guide's description of CIAO value parameters ``[soft scale] (hard scale) hard value``.

Orientation: the first stored line is the bottom of the image (NanoScope scans and stores from
the bottom up; Gwyddion flips it for display), so rows are kept as stored: row 0 = bottom.
Pixel spacing: ``dx = scan size x / Samps/line``, ``dy = scan size y / Number of lines``.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from arsurf.errors import CorruptScan, UnsupportedScan
from arsurf.scan.readers._common import (
    Channel,
    check_data_size,
    check_scale,
    check_shape,
    frombuffer,
    make_scan,
    parse_float,
    parse_int,
    parse_unit,
    select_channel,
    unique_names,
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
    """The soft scale ``@<sens>``: (its hard value, its unit as written), e.g. ``V 57.39 nm/V``
    -> (57.39, 'nm/V'); ``V 1.000000`` (a unitless sensitivity) -> (1.0, '')."""
    text = _lookup(sections, "@" + sens)
    if text is None:
        raise CorruptScan(f"{path}: the Z scale refers to [{sens}] but the header has no '@{sens}' line")
    m = re.match(r"^\s*\w*\s*([-+]?[\d.]+(?:[eE][-+]?\d+)?)\s*(\S*)", text)
    if not m:
        raise CorruptScan(f"{path}: cannot read the sensitivity '@{sens}: {text}'")
    return parse_float(path, m.group(1), "@" + sens), m.group(2)


def _log_inner(unit: str) -> str | None:
    """``"log(Pa)"`` -> ``"Pa"``; None when ``unit`` is not a ``log(...)`` unit."""
    u = unit.strip()
    return u[4:-1] if u.lower().startswith("log(") and u.endswith(")") else None


def resolve_unit(soft_unit: str, hard_unit: str) -> tuple[float, str, bool, bool]:
    """Unit of ``hard value x soft scale`` for a NanoScope image channel.

    Returns ``(factor, unit, log10, resolved)``: multiply the product of the two numbers by
    ``factor`` to get ``unit`` (an SI base unit, or ``Arb``); when ``log10`` the product is the
    base-10 logarithm of a value in ``unit`` (after ``factor``, see :func:`read`); ``resolved``
    is False when the soft scale's denominator does not match the hard value's unit (the unit is
    then the unsimplified product).

    The soft scale cancels the hard unit: ``nm/V x V -> nm``, ``V/Arb x Arb -> V``,
    ``log(Pa)/log(Arb) x log(Arb) -> log(Pa)``, ``N/m*Arb x Arb -> N/m`` (v9 headers write a
    stiffness sensitivity that way); a unitless soft scale (``V 1.000000``) leaves the hard unit
    (``Arb``, ``V``). Gwyddion (nanoscope.c, ``get_physical_scale``) calls that last case
    ``V``; we keep the hard value's own unit, which the header writes.

    Examples
    --------
    >>> resolve_unit("nm/V", "V")
    (1e-09, 'm', False, True)
    >>> resolve_unit("log(Pa)/log(Arb)", "log(Arb)")
    (1.0, 'Pa', True, True)
    """
    soft, hard = (soft_unit or "").strip(), (hard_unit or "").strip()
    if not soft:
        num, resolved = hard, True
    else:
        if hard and soft.endswith("*" + hard):
            num, den = soft[: -len(hard) - 1], hard
        elif "/" in soft:
            num, den = soft.rsplit("/", 1)
        else:
            num, den = soft, ""
        hard_log, den_log = _log_inner(hard), _log_inner(den)
        if den == hard:
            num, resolved = num, True
        elif hard_log is None and den_log is None and den and hard and parse_unit(den)[1] == parse_unit(hard)[1]:
            # same base, other prefixes (hard value in mV, soft scale per V)
            f = parse_unit(hard)[0] / parse_unit(den)[0]
            fac, base, lg, _ = resolve_unit(num, "")
            return fac * f, base, lg, True
        else:
            return 1.0, f"{num}*{hard}/{den}" if den else f"{num}*{hard}", False, False
    inner = _log_inner(num)
    if inner is not None:
        factor, base = parse_unit(inner)
        return factor, base, True, resolved
    factor, base = parse_unit(num)
    return factor, base, False, resolved


def channel_scale(path, sections, d: dict[str, str], bpp: int) -> dict:
    """How to turn one image's stored integers into physical values (the NanoScope rules).

    ``\\@2:Z scale: V [Sens. X] (hard scale/LSB) hard value`` names a soft scale
    ``\\@Sens. X: V value unit``; a stored integer is worth
    ``hard value / 2**(8 Bytes/pixel) x soft value`` in the unit of :func:`resolve_unit`
    (Bytes/pixel sets the LSB even where v9.2+ stores 4-byte integers; Gwyddion's
    ``get_bpp_and_qbpp``). Returns ``per_lsb`` (file unit per LSB), ``factor``, ``unit``,
    ``log10``, ``resolved``, ``calibrated`` (False when the file leaves the channel in ``Arb``:
    a unitless sensitivity on an arbitrary-unit hard value) and the lines used.
    """
    zline = d.get("@2:z scale") or d.get("@4:z scale")
    if zline is None:
        raise CorruptScan(f"{path}: image {_image_name(d, 0)!r} has no '@2:Z scale' line")
    m = _ZSCALE.match(zline)
    if not m:
        raise CorruptScan(f"{path}: cannot read '@2:Z scale: {zline}'")
    hard_value = parse_float(path, m.group("value"), "the Z scale hard value")
    hard_unit = m.group("unit") or "V"
    per_lsb = hard_value / float(2 ** (8 * bpp))
    sens = (m.group("sens") or "").strip()
    soft_value, soft_unit = _soft_scale(path, sections, sens) if sens else (1.0, "")
    factor, unit, log10, resolved = resolve_unit(soft_unit, hard_unit)
    return {
        "per_lsb": per_lsb * soft_value, "factor": factor, "unit": unit, "log10": log10, "resolved": resolved,
        "calibrated": resolved and unit.lower() != "arb",
        "z_scale_line": zline, "soft_scale": sens or None, "soft_value": soft_value, "soft_unit": soft_unit,
        "hard_value": hard_value, "hard_unit": hard_unit,
    }


def check_layout(path, buf: bytes, sections) -> None:
    """Refuse a file whose data blocks do not sit where the header says.

    The first section's ``Data length`` is the size of the text header (40960 or 80960 bytes on
    the real files); every section with a ``Data offset`` and ``Data length`` (the images) owns
    that many bytes, after the header, without overlap, and the last block ends where the file
    ends (NanoScope writes the header, then the blocks, nothing else; both real files, v5.31 and
    v9.3, have exactly that size). A digit changed in an offset or a length, or bytes inserted
    into the header (which shifts every block), would otherwise read other bytes as the image.
    """
    text_end = buf.find(_END) + len(_END)
    first = sections[0][1] if sections else {}
    header = parse_int(path, first.get("data length", str(text_end)), "the header size (File list Data length)")
    if not text_end <= header <= len(buf):
        raise CorruptScan(f"{path}: the header size (File list Data length) is {header}, but the text header ends at "
                          f"byte {text_end} and the file has {len(buf)} bytes; the header is damaged")
    blocks = []
    for name, d in sections[1:]:
        if "data offset" in d and "data length" in d:
            off = parse_int(path, d["data offset"], f"{name} Data offset")
            length = parse_int(path, d["data length"], f"{name} Data length")
            if off < header or length < 0:
                raise CorruptScan(f"{path}: {name} has Data offset {off} and Data length {length}; its data must "
                                  f"start after the {header}-byte header; the header is damaged")
            blocks.append((off, off + length, name))
    blocks.sort()
    for (a0, a1, an), (b0, b1, bn) in zip(blocks, blocks[1:]):
        if b0 < a1:
            raise CorruptScan(f"{path}: the data of {bn} (bytes {b0}..{b1}) overlap those of {an} (bytes {a0}..{a1}); "
                              "an offset or a length in the header is damaged")
    if blocks:
        check_data_size(path, len(buf) - header, blocks[-1][1] - header,
                        f"the {len(blocks)} data blocks the header lists", exact=True)


def _image_name(d: dict[str, str], i: int) -> str:
    for key in ("@2:image data", "@3:image data", "image data"):
        if key in d:
            v = d[key]
            m = re.search(r'"([^"]*)"', v) or re.search(r"\[([^\]]*)\]", v)
            if m and m.group(1):
                return m.group(1)
    return f"Image {i}"


def read(path: Path | str, channel: str | None = None):
    """Read one image of a NanoScope file in SI units (default: the Height Sensor channel when
    recorded, else the first trace, else retrace, height).

    Channel names are ``"<Image Data name> (Trace)"`` or ``"(Retrace)"``, e.g.
    ``"Height (Retrace)"``; the bare ``"Height"`` works when it is unique. Each channel comes in
    the unit its Z scale and soft scale resolve to (:func:`channel_scale`): m, V, Pa, N, J, deg...
    or ``Arb`` when the file does not calibrate it (``metadata["calibrated"]`` is then False).
    A ``log(...)`` channel (``LogDMTModulus``) stores the base-10 logarithm of a value: it is
    returned as ``10**value`` in the inner unit, flagged ``metadata["log10_decoded"]``.
    """
    buf = Path(path).read_bytes()
    sections = parse_header(path, buf)
    images = [d for name, d in sections if name.lower() in ("ciao image list", "afm image list", "stm image list")]
    if not images:
        if buf.startswith(_MAGICS[3]):
            raise UnsupportedScan(f"{path}: a NanoScope force-curve file ('\\*Force file list') without an image; "
                                  "arsurf reads height images, not force curves: give the scan's image file")
        raise CorruptScan(f"{path}: the header lists no image (no '\\*Ciao image list' section)")
    chans: list[Channel] = []
    for i, d in enumerate(images):
        name = _image_name(d, i)
        line_dir = d.get("line direction", "").strip()
        direction = {"trace": "forward", "retrace": "backward"}.get(line_dir.lower())
        label = f"{name} ({line_dir})" if line_dir else name
        try:  # the unit of every channel, for the listing (a damaged one is reported when read)
            unit = channel_scale(path, sections, d, 2)["unit"]
        except CorruptScan:
            unit = ""
        chans.append(Channel(label, key=i, unit=unit, direction=direction))
    if channel is None:  # the default is the height: the Height Sensor when recorded, as Bruker's software does
        unique_names(chans)
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
    # v9.2+ files store every image as 4-byte integers while some lists still say "Bytes/pixel: 2"
    # (Gwyddion: "in version 9.2 all data magically became 32bit"): the data length says how wide
    # the stored integers are; the Z scale still counts in units of 2^(8 Bytes/pixel)
    width = 4 if (length == nx * ny * 4 and bpp == 2) else bpp
    if length < nx * ny * width:
        raise CorruptScan(f"{path}: Data length {length} is less than {nx}x{ny}x{width} bytes")
    check_layout(path, buf, sections)
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

    sc = channel_scale(path, sections, d, bpp)
    chan.unit = sc["unit"]
    check_scale(path, sc["per_lsb"], f"the z scale of channel {chan.name!r} (per LSB: {sc['z_scale_line']})")
    if sc["log10"]:  # the file stores log10 of the quantity: decode it (overflow -> inf -> NaN, counted)
        with np.errstate(over="ignore", invalid="ignore"):
            data, z_factor = np.power(10.0, raw * sc["per_lsb"]), sc["factor"]
    else:
        data, z_factor = raw, sc["per_lsb"] * sc["factor"]
    version = _lookup(sections, "Version")
    return make_scan(
        path, FORMAT, data, xs / nx, ys / ny, chan, chans, rows_flipped=False,
        z_factor=z_factor, z_unit=sc["unit"],
        instrument={
            "software": "NanoScope", "version": version,
            "description": _lookup(sections, "Description"), "microscope": _lookup(sections, "Microscope"),
            "date": _lookup(sections, "Date"),
        },
        extra={"file_z_unit": f"log({sc['unit']})" if sc["log10"] else sc["unit"],
               "z_scale_line": sc["z_scale_line"], "z_per_lsb": None if sc["log10"] else z_factor,
               "soft_scale": {"name": sc["soft_scale"], "value": sc["soft_value"], "unit": sc["soft_unit"]},
               "hard_value": {"value": sc["hard_value"], "unit": sc["hard_unit"]},
               "calibrated": sc["calibrated"], "unit_resolved": sc["resolved"], "log10_decoded": sc["log10"],
               "bytes_per_pixel": bpp, "stored_bytes_per_pixel": width,
               "line_direction": d.get("line direction"), "frame_direction": d.get("frame direction"),
               "sample_poisson_ratio": sample_poisson_ratio(sections)},
    )


def sample_poisson_ratio(sections) -> float | str | None:
    """The ``Sample Poisson's Ratio`` of the header (the ratio the instrument's DMT fit used to turn
    the reduced modulus into ``DMTModulus``): a float, the text as written when it is not a number
    (refused where it is used, :mod:`arsurf.contact.material_map`), or None without one."""
    text = _lookup(sections, "Sample Poisson's Ratio")
    if text is None:
        return None
    try:
        return float(text.split()[0])
    except (ValueError, IndexError):
        return text.strip()
