"""NT-MDT ``.mdt`` reader (Nova / Nova PX / Image Analysis files): scanned-image and MDA frames.

Library: our own parser. No maintained reader of the field fits: SciFiReaders' ``MDTReader``
needs sidpy, reads MDA frames only (not the classic scanned frames that hold most topography),
converts pixel by pixel in Python and returns the image transposed; Gwyddion's ``nt-mdt.c`` is
the reference we follow (GPL C, not callable from Python). The layout below is Gwyddion's.

File (little-endian): a 33-byte header -- magic ``01 b0 93 ff``, the file size without the
header (u32, so the file is exactly that + 33 bytes), the last frame index (u16 at byte 12) --
then the frames one after the other. Each frame starts with a 22-byte header: its size (u32,
header included), type (u16: 0 scanned, 1 spectroscopy, 3 text, 105 old MDA, 106 MDA, 107
palette, 190 new curves, 201 curves), version, date and time, and the size of its variables
block (u16).

Scanned frame (type 0): the variables start with three axis scales (x, y, z: offset f32, step
f32, unit code i16; the unit codes are Gwyddion's ``MDTUnit`` table), then the ADC mode (u8),
...; at 22 + variables size the "frame mode" block (mode, xres, yres, number of dots: u16 each),
the dots (14 + 16 n bytes when n > 0), ``xres * yres`` int16 values, then the title (u32 length
+ cp1251 text). Value = ``z_offset + z_step * raw`` in the z unit; pixel spacing ``|x_step|``,
``|y_step|`` in the xy unit (Gwyddion: ``xreal = xres * x_step``).

MDA frame (type 106, two dimensions and one measurand): a block of sizes (head size, name and
XML comment sizes, ...), the title (cp1251), then the calibrations: for each dimension and
measurand a record with ``bias``, ``scale``, ``min/max index``, data type (-1/1 int8/uint8,
-2/2 int16, -4/4 int32, -8/8 int64, -5892 float32, -13320 float64) and a unit string.
Value = ``bias + scale * raw``; dimension 0 is x (fast), 1 is y; pixel spacing = the
dimension's ``scale`` (one index step).

Orientation: both frame kinds store the bottom line first (Gwyddion mirrors them vertically for
its top-first display), so rows are kept: row 0 = bottom.

Channel names: the frame title (``Height``, ``1F:Iprobe``...; ``1F``/``1B`` = first pass
forward/backward), or the ADC mode when the title is empty; repeated names get ``#2``...
Other frame kinds (spectra, curves, text, palettes) are not images and are skipped.
"""
from __future__ import annotations

import re
import struct
from pathlib import Path

import numpy as np

from arsurf.errors import CorruptScan
from arsurf.scan.readers._common import (
    Channel,
    check_shape,
    frombuffer,
    make_scan,
    parse_unit,
    select_channel,
)

MAGIC = b"\x01\xb0\x93\xff"
EXTENSIONS = (".mdt",)
FORMAT = "mdt"
FILE_HEADER = 33
FRAME_HEADER = 22
_AXIS_SCALES = 30
_SCAN_VARS_MIN = 77
_FRAME_MODE = 8
SCANNED, MDA = 0, 106
_FRAME_KINDS = {0: "scanned", 1: "spectroscopy", 3: "text", 105: "old MDA", 106: "MDA", 107: "palette",
                190: "curves (new)", 201: "curves"}

#: NT-MDT unit codes of scanned frames (Gwyddion's ``MDTUnit``), as unit strings parse_unit knows
UNITS = {
    -10: "1/cm", -5: "m", -4: "cm", -3: "mm", -2: "um", -1: "nm", 0: "\u00c5", 1: "nA", 2: "V", 3: "",
    4: "kHz", 5: "deg", 6: "%", 7: "degC", 8: "V", 9: "s", 10: "ms", 11: "us", 12: "ns", 13: "", 14: "px",
    20: "A", 21: "mA", 22: "uA", 23: "nA", 24: "pA", 25: "V", 26: "mV", 27: "uV", 28: "nV", 29: "pV",
    30: "N", 31: "mN", 32: "uN", 33: "nN", 34: "pN",
}
#: ADC modes (Gwyddion's ``MDTADCMode``): the channel name of an untitled scanned frame
ADC_MODES = {
    0: "Height", 1: "DFL", 2: "Lateral F", 3: "Bias V", 4: "Current", 5: "FB Out", 6: "MAG", 7: "MAG Sin",
    8: "MAG Cos", 9: "RMS", 10: "CalcMag", 11: "Phase1", 12: "Phase2", 13: "CalcPhase", 14: "Ex1", 15: "Ex2",
    16: "HvX", 17: "HvY", 18: "Snap Back",
}
#: MDA data types -> numpy dtype
MDA_TYPES = {-1: "<i1", 1: "<u1", -2: "<i2", 2: "<u2", -4: "<i4", 4: "<u4", -8: "<i8", 8: "<u8",
             -(4 + 23 * 256): "<f4", -(8 + 52 * 256): "<f8"}
#: MDA SI unit codes used when a calibration has no unit string (Gwyddion's ``unitCodeForSiCode``)
_MDA_SI = {0x1: "", 0x101: "m", 0x100001: "A", 0xFFFD010200: "V", 0x1000001: "s"}
_MAX_FRAMES = 65536
_PASS = re.compile(r"^\s*\d+\s*([FB])\s*:")


def sniff(head: bytes) -> bool:
    """True when the file starts with the NT-MDT magic ``01 b0 93 ff``."""
    return head[:4] == MAGIC


def _u(fmt: str, buf: bytes, off: int, end: int, path, what: str):
    n = struct.calcsize(fmt)
    if off < 0 or off + n > end:
        raise CorruptScan(f"{path}: {what} lies past the end of its frame or file (truncated or corrupt)")
    return struct.unpack_from(fmt, buf, off)


def _title(raw: bytes) -> str:
    return raw.decode("cp1251", "replace")


def _scanned(path, buf: bytes, start: int, size: int, var_size: int, index: int) -> Channel:
    end = start + size
    if var_size < _AXIS_SCALES + _SCAN_VARS_MIN:
        raise CorruptScan(f"{path}: frame {index}: variables block of {var_size} bytes is too short for a scanned "
                          f"frame (needs {_AXIS_SCALES + _SCAN_VARS_MIN})")
    p = start + FRAME_HEADER
    xo, xs, xu, yo, ys, yu, zo, zs, zu = _u("<ffhffhffh", buf, p, end, path, f"frame {index} axis scales")
    adc = _u("<B", buf, p + _AXIS_SCALES, end, path, f"frame {index} ADC mode")[0]
    q = start + FRAME_HEADER + var_size
    _mode, nx, ny, ndots = _u("<4H", buf, q, end, path, f"frame {index} frame-mode block")
    check_shape(path, nx, ny)
    data = q + _FRAME_MODE + (14 + 16 * ndots if ndots else 0)
    title_at = data + 2 * nx * ny
    if title_at > end:
        raise CorruptScan(f"{path}: frame {index}: {nx}x{ny} int16 values (and {ndots} dots) need {title_at - start} "
                          f"bytes but the frame has {size} (truncated or corrupt)")
    title = ""
    if end - title_at > 4:
        (tlen,) = struct.unpack_from("<I", buf, title_at)
        if 0 < tlen <= end - title_at - 4:
            title = _title(buf[title_at + 4 : title_at + 4 + tlen])
    for code, what in ((xu, "x"), (yu, "y"), (zu, "z")):
        if code not in UNITS:
            raise CorruptScan(f"{path}: frame {index}: the {what} unit code {code} is not an NT-MDT unit")
    if parse_unit(UNITS[xu])[1] != "m" or parse_unit(UNITS[yu])[1] != "m":
        raise CorruptScan(f"{path}: frame {index}: x/y units {UNITS[xu]!r}/{UNITS[yu]!r} are not lengths")
    name = title.strip() or ADC_MODES.get(adc, f"Frame {index}")
    return Channel(name, key=("scanned", index, data, nx, ny), unit=UNITS[zu], direction=_direction(name),
                   extra={"scale": (xs, ys, zo, zs, UNITS[xu], UNITS[yu]), "adc_mode": ADC_MODES.get(adc, adc),
                          "frame": index})


def _mda_calibration(path, buf: bytes, p: int, end: int, index: int) -> tuple[dict, int]:
    tot, struct_len = _u("<II", buf, p, end, path, f"frame {index} MDA calibration")
    if tot < 8 or p + tot > end or struct_len > tot - 8:
        raise CorruptScan(f"{path}: frame {index}: an MDA calibration record claims {tot} bytes (corrupt frame)")
    name_len, comment_len, unit_len = _u("<3I", buf, p + 8, end, path, f"frame {index} MDA calibration")
    si, _acc = _u("<Qd", buf, p + 20, end, path, f"frame {index} MDA calibration")
    bias, scale, lo, hi, dtype, author_len = _u("<ddQQiI", buf, p + 44, end, path, f"frame {index} MDA calibration")
    s = p + 8 + struct_len
    if s + name_len + comment_len + unit_len > p + tot:
        raise CorruptScan(f"{path}: frame {index}: an MDA calibration's strings run past its record (corrupt frame)")
    unit = buf[s + name_len + comment_len : s + name_len + comment_len + unit_len].decode("cp1251", "replace")
    if not unit:
        unit = _MDA_SI.get(si, "")
    return {"bias": bias, "scale": scale, "lo": lo, "hi": hi, "type": dtype, "unit": unit.strip()}, p + tot


def _mda(path, buf: bytes, start: int, size: int, index: int) -> Channel | None:
    end = start + size
    p = start + FRAME_HEADER
    head_size, _tot = _u("<II", buf, p, end, path, f"frame {index} MDA header")
    name_size, comm_size, view_size, spec_size, src_size = _u("<5I", buf, p + 44, end, path, f"frame {index} MDA header")
    t = p + head_size
    if head_size < 72 or t + name_size + comm_size > end:
        raise CorruptScan(f"{path}: frame {index}: MDA header sizes ({head_size}, {name_size}, {comm_size}) run past "
                          "the frame (corrupt)")
    title = _title(buf[t : t + name_size])
    r = t + name_size + comm_size + spec_size + view_size + src_size + 4
    (struct_len,) = _u("<I", buf, r, end, path, f"frame {index} MDA array header")
    _n, _cell, ndim, nmeas = _u("<QIII", buf, r + 4, end, path, f"frame {index} MDA array header")
    if ndim != 2 or nmeas != 1:
        return None  # spectra, Raman cubes: not a height map
    r += 4 + struct_len
    cals = []
    for _ in range(3):
        cal, r = _mda_calibration(path, buf, r, end, index)
        cals.append(cal)
    xcal, ycal, zcal = cals
    nx, ny = xcal["hi"] - xcal["lo"] + 1, ycal["hi"] - ycal["lo"] + 1
    if not (0 < nx <= 1 << 20 and 0 < ny <= 1 << 20):
        raise CorruptScan(f"{path}: frame {index}: MDA index ranges give {nx} x {ny} pixels (corrupt frame)")
    check_shape(path, int(nx), int(ny))
    if zcal["type"] not in MDA_TYPES:
        raise CorruptScan(f"{path}: frame {index}: MDA data type {zcal['type']} is not one of NT-MDT's")
    dt = np.dtype(MDA_TYPES[zcal["type"]])
    if r + nx * ny * dt.itemsize > end:
        raise CorruptScan(f"{path}: frame {index}: {nx}x{ny} {dt} values run past the end of the frame (truncated)")
    for cal, what in ((xcal, "x"), (ycal, "y")):
        if parse_unit(cal["unit"])[1] != "m":
            raise CorruptScan(f"{path}: frame {index}: the MDA {what} unit {cal['unit']!r} is not a length")
    name = title.strip() or f"Frame {index}"
    return Channel(name, key=("mda", index, r, int(nx), int(ny)), unit=zcal["unit"], direction=_direction(name),
                   extra={"scale": (xcal["scale"], ycal["scale"], zcal["bias"], zcal["scale"], xcal["unit"],
                                    ycal["unit"]), "dtype": dt.str, "frame": index})


def _direction(name: str) -> str | None:
    m = _PASS.match(name)
    if m:
        return "forward" if m.group(1) == "F" else "backward"
    return None


def frames(path, buf: bytes) -> tuple[list[Channel], list[tuple[int, str]]]:
    """The image channels of an ``.mdt`` buffer and every frame's (index, kind), checking the
    file and frame sizes against the headers."""
    if len(buf) < FILE_HEADER or buf[:4] != MAGIC:
        raise CorruptScan(f"{path}: not an NT-MDT .mdt file (no 01 b0 93 ff magic or shorter than 33 bytes)")
    size, = struct.unpack_from("<I", buf, 4)
    last, = struct.unpack_from("<H", buf, 12)
    if size + FILE_HEADER != len(buf):
        raise CorruptScan(f"{path}: the header gives {size + FILE_HEADER} bytes but the file has {len(buf)} "
                          "(truncated or corrupt)")
    nframes = last + 1
    if nframes * FRAME_HEADER > size:
        raise CorruptScan(f"{path}: the header lists {nframes} frames, more than {size} bytes can hold")
    chans: list[Channel] = []
    kinds = []
    p = FILE_HEADER
    for i in range(nframes):
        fsize, ftype = _u("<IH", buf, p, len(buf), path, f"frame {i} header")
        var_size, = _u("<H", buf, p + 20, len(buf), path, f"frame {i} header")
        if fsize < FRAME_HEADER + var_size or p + fsize > len(buf):
            raise CorruptScan(f"{path}: frame {i} claims {fsize} bytes (variables {var_size}) at byte {p} of a "
                              f"{len(buf)}-byte file (truncated or corrupt)")
        kinds.append((i, _FRAME_KINDS.get(ftype, f"type {ftype}")))
        if ftype == SCANNED:
            chans.append(_scanned(path, buf, p, fsize, var_size, i))
        elif ftype == MDA:
            c = _mda(path, buf, p, fsize, i)
            if c is not None:
                chans.append(c)
        p += fsize
    return chans, kinds


def read(path: Path | str, channel: str | None = None):
    """Read one image frame of an NT-MDT ``.mdt`` file in SI units (default: the height).

    Channel names are the frame titles (see the module docstring); ``metadata["frame"]`` is the
    frame index in the file and ``metadata["frames"]`` lists every frame's kind.
    """
    path = Path(path)
    buf = path.read_bytes()
    chans, kinds = frames(path, buf)
    if not chans:
        raise CorruptScan(f"{path}: no image frame (frames: {[k for _, k in kinds][:20]})")
    chan = select_channel(path, chans, channel)
    kind, index, off, nx, ny = chan.key
    xs, ys, z0, zs, xu, yu = chan.extra["scale"]
    dtype = "<i2" if kind == "scanned" else chan.extra["dtype"]
    raw = frombuffer(path, buf, off, dtype, nx * ny, chan.name).reshape(ny, nx)
    if not (np.isfinite(zs) and zs != 0.0 and np.isfinite(z0)):
        raise CorruptScan(f"{path}: frame {index}: the z scale {zs!r} / offset {z0!r} of {chan.name!r} cannot map "
                          "raw values to heights (damaged header)")
    with np.errstate(invalid="ignore", over="ignore"):
        data = z0 + zs * raw
    fz, base = parse_unit(chan.unit)
    dx = abs(float(xs)) * parse_unit(xu)[0]
    dy = abs(float(ys)) * parse_unit(yu)[0]
    return make_scan(path, FORMAT, data, dx, dy, chan, chans, rows_flipped=False, z_factor=fz, z_unit=base,
                     instrument={"software": "NT-MDT", "frame_kind": kind},
                     extra={"frame": index, "frames": [f"{i}: {k}" for i, k in kinds],
                            "adc_mode": chan.extra.get("adc_mode")})
