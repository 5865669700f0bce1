"""High-speed AFM ``.asd`` reader (Kodera/Ando lab format, RIBM/Toshio Ando HS-AFM; file versions 0, 1, 2).

An ``.asd`` file is a movie: up to two channels (topography ``TP``, error ``ER``, phase ``PH``),
each a sequence of frames. Select the frame with ``load_scan(path, frame=N)`` (``arsurf ...
--frame N``), counted from 0; the channel with ``channel="Topography"`` / ``"Phase"`` /
``"Error"`` (or the two-letter codes). Default: frame 0 of the topography.

Library: our own parser. AFMReader's ``asd.load_asd`` (GPL, imports matplotlib) decodes every
frame of a channel into memory and trusts every header field; libasd (MIT, a C++ binding) does
the same without bounds checks. Both agree on the layout and the conversion, which we follow;
the tests compare our pixel sizes with AFMReader's published values and our heights with
libasd's (when installed) on the real samples.

Layout (little-endian): ``int32`` file version, then the file header:

- version 0: channel kinds as two ``int16`` ASCII codes, header size, frame-header size,
  operator-name size, comment-offset size, comment size (``int32``), pixels and scan size in nm
  (``int16`` x, y), frame time, z piezo extension [nm/V], z piezo gain (``float32``), A/D range
  code, A/D bits, ... The frames start after the header *and* the comment (header size +
  comment-offset size + comment size), as both readers find.
- versions 1 and 2: header size, frame-header size, text encoding, operator-name size, comment
  size, the two channel kinds (``int32``), initial and actual frame counts, scan direction,
  file id, pixels and scan size in nm (``int32``), ..., frame time, error-sensor sensitivity
  [nm/V], phase sensitivity [deg/V], ..., A/D range code and bits, ..., z piezo extension and
  gain (``float32``). The frames start at the header size.

Then every frame of channel 1, then every frame of channel 2; a frame is a header of
frame-header-size bytes (frame number, max/min data, offsets, tilt...) and ``ny * nx`` int16
A/D levels, the fast axis (x) first.

Conversion (AFMReader, libasd): the A/D range code gives a bipolar range ``+-V`` (``0x10000``
1 V, ``0x20000`` 2.5 V, ``0x40000`` 5 V) or a unipolar ``0..V`` (``1`` 1 V, ``2`` 2.5 V, ``3``
9.99 V, ``4`` 5 V); with ``N = 2**bits`` levels a level ``l`` is the voltage
:math:`v = V - 2 l V / N` (bipolar) or :math:`v = -l V / N` (unipolar, as AFMReader), and the
value is :math:`c\\,v` with :math:`c` = z piezo gain x z piezo extension [nm] for topography,
``-`` error sensitivity [nm] for error, ``-`` phase sensitivity [deg] for phase.
Pixel spacing: scan size / pixels on each axis (AFMReader).

Orientation: the format does not say which line is at the top; both reference readers keep the
stored order and so do we (row 0 = the first line stored, ``rows_flipped`` False).
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from arsurf.errors import ChannelNotFound, CorruptScan
from arsurf.scan.readers._common import Channel, check_shape, make_scan, select_channel

EXTENSIONS = (".asd",)
FORMAT = "asd"
#: channel kind code (two ASCII letters, little-endian) -> (name, unit of the converted values)
KINDS = {0x5054: ("Topography", "nm"), 0x5245: ("Error", "nm"), 0x4850: ("Phase", "deg")}
_CODES = {"TP": 0x5054, "ER": 0x5245, "PH": 0x4850}
#: A/D range code -> (volts, bipolar)
AD_RANGES = {0x1: (1.0, False), 0x2: (2.5, False), 0x3: (9.99, False), 0x4: (5.0, False),
             0x10000: (1.0, True), 0x20000: (2.5, True), 0x40000: (5.0, True)}
_HEAD = 1 << 20
_MAX_FRAMES = 1 << 24


def _v0(b: bytes) -> dict:
    (ch1, ch2, hsize, fhsize, name, coff, csize, nx, ny, xnm, ynm, ftime, zext, zgain, adr, bits) = struct.unpack_from(
        "<hhiiiiihhhhfffIi", b, 4)
    # is_averaged (1) window (4) pad (2) date (2+5) rounding (1) max ranges (8) 3 x int32, init, num, afm id,
    # file id (2), operator name, sensor sensitivity, phase sensitivity, scan direction
    nframes, = struct.unpack_from("<i", b, 95)
    p = 105 + max(name, 0)
    sens, phase, direction = struct.unpack_from("<ffi", b, p) if p + 12 <= len(b) else (np.nan, np.nan, 0)
    return {"version": 0, "kinds": (ch1, ch2), "header_size": hsize, "frame_header_size": fhsize,
            "name_size": name, "comment_offset": coff, "comment_size": csize, "nx": nx, "ny": ny,
            "x_nm": xnm, "y_nm": ynm, "frame_time": ftime, "z_extension": zext, "z_gain": zgain, "ad_range": adr,
            "bits": bits, "frames": nframes, "error_sensitivity": sens, "phase_sensitivity": phase,
            "scan_direction": direction, "data_offset": hsize + coff + csize}


def _v12(b: bytes, version: int) -> dict:
    (hsize, fhsize, _enc, name, csize, ch1, ch2, _init, nframes, direction, _fid, nx, ny, xnm, ynm) = \
        struct.unpack_from("<15i", b, 4)
    # averaged (1) window (4) date (6 x 4) rounding (2 x 4) -> frame time at 101
    ftime, sens, phase = struct.unpack_from("<fff", b, 101)
    adr, bits = struct.unpack_from("<Ii", b, 133)
    zext, zgain = struct.unpack_from("<ff", b, 157)
    return {"version": version, "kinds": (ch1, ch2), "header_size": hsize, "frame_header_size": fhsize,
            "name_size": name, "comment_size": csize, "nx": nx, "ny": ny, "x_nm": xnm, "y_nm": ynm,
            "frame_time": ftime, "z_extension": zext, "z_gain": zgain, "ad_range": adr, "bits": bits,
            "frames": nframes, "error_sensitivity": sens, "phase_sensitivity": phase, "scan_direction": direction,
            "data_offset": hsize}


_FIXED = {0: 105, 1: 165, 2: 165}


def sniff(head: bytes) -> bool:
    """True for the head of an ``.asd`` file: version 0, 1 or 2 followed by channel-kind codes
    the format defines (TP, ER, PH or none) at their places."""
    if len(head) < 32:
        return False
    version, = struct.unpack_from("<i", head, 0)
    if version == 0:
        ch1, ch2 = struct.unpack_from("<hh", head, 4)
        fh, = struct.unpack_from("<i", head, 12)
        return ch1 in KINDS and (ch2 in KINDS or ch2 == 0) and 0 <= fh <= 4096
    if version in (1, 2):
        hsize, fh = struct.unpack_from("<ii", head, 4)
        ch1, ch2 = struct.unpack_from("<ii", head, 24)
        return ch1 in KINDS and (ch2 in KINDS or ch2 == 0) and 0 <= fh <= 4096 and 0 < hsize < _HEAD
    return False


def parse_header(path, head: bytes, size: int) -> dict:
    """The header fields an image needs, each checked against the format and the file size."""
    if len(head) < 8:
        raise CorruptScan(f"{path}: {len(head)} bytes are too few for an .asd header")
    version, = struct.unpack_from("<i", head, 0)
    if version not in _FIXED:
        raise CorruptScan(f"{path}: .asd file version {version} is not 0, 1 or 2")
    if len(head) < _FIXED[version] + 12:
        raise CorruptScan(f"{path}: the .asd version-{version} header is cut at {len(head)} bytes (truncated)")
    h = _v0(head) if version == 0 else _v12(head, version)
    for key in ("header_size", "frame_header_size", "name_size", "comment_size"):
        if not 0 <= h[key] < _HEAD:
            raise CorruptScan(f"{path}: the header field {key} is {h[key]} (corrupt header)")
    if version == 0 and not 0 <= h["comment_offset"] < _HEAD:
        raise CorruptScan(f"{path}: the header field comment_offset_size is {h['comment_offset']} (corrupt header)")
    if h["header_size"] < _FIXED[version] or h["data_offset"] > size:
        raise CorruptScan(f"{path}: the header size {h['header_size']} is impossible for version {version} in a "
                          f"{size}-byte file (corrupt header)")
    if h["frame_header_size"] < 0:
        raise CorruptScan(f"{path}: negative frame-header size {h['frame_header_size']}")
    check_shape(path, h["nx"], h["ny"])
    if not 1 <= h["frames"] <= _MAX_FRAMES:
        raise CorruptScan(f"{path}: the header gives {h['frames']} frames")
    if h["ad_range"] not in AD_RANGES:
        raise CorruptScan(f"{path}: A/D range code {h['ad_range']:#x} is not one the format defines "
                          f"({', '.join(f'{k:#x}' for k in AD_RANGES)})")
    if not 1 <= h["bits"] <= 16:
        raise CorruptScan(f"{path}: A/D resolution of {h['bits']} bits is impossible for int16 data")
    k1, k2 = h["kinds"]
    if k1 not in KINDS or (k2 not in KINDS and k2 != 0):
        raise CorruptScan(f"{path}: channel kinds {k1:#x}/{k2:#x} are not TP, ER or PH")
    nch = 2 if k2 in KINDS else 1
    frame_bytes = h["frame_header_size"] + 2 * h["nx"] * h["ny"]
    need = h["data_offset"] + nch * h["frames"] * frame_bytes
    if need > size:
        raise CorruptScan(f"{path}: {nch} channel(s) x {h['frames']} frames of {h['nx']}x{h['ny']} need {need} "
                          f"bytes but the file has {size} (truncated)")
    h["channels"] = nch
    h["frame_bytes"] = frame_bytes
    return h


def coefficient(path, h: dict, kind: int) -> float:
    """Physical units per volt of a channel kind: nm/V for TP and ER, deg/V for PH."""
    if kind == 0x5054:
        c = h["z_gain"] * h["z_extension"]
        what = "z piezo gain x extension"
    elif kind == 0x5245:
        c, what = -h["error_sensitivity"], "error-sensor sensitivity"
    else:
        c, what = -h["phase_sensitivity"], "phase sensitivity"
    if c == 0.0:
        raise CorruptScan(f"{path}: the file gives a {what} of 0, so its {KINDS[kind][0]} channel is not calibrated "
                          "(every value would be 0); choose another channel")
    if not (np.isfinite(c) and abs(c) < 1e7):
        raise CorruptScan(f"{path}: the {what} is {c!r}: it cannot convert A/D levels of {KINDS[kind][0]} "
                          "(damaged header)")
    return float(c)


def levels_to_volts(levels: np.ndarray, ad_range: int, bits: int) -> np.ndarray:
    """A/D levels to volts: :math:`V - 2lV/N` (bipolar) or :math:`-lV/N` (unipolar), :math:`N = 2^{bits}`."""
    volts, bipolar = AD_RANGES[ad_range]
    n = float(1 << bits)
    lv = levels.astype(np.float64)
    return volts - 2.0 * lv * volts / n if bipolar else -lv * volts / n


def read(path: Path | str, channel: str | None = None, frame: int | None = None):
    """Read one frame of one channel of an ``.asd`` movie in SI units (default: frame 0 of the
    topography); ``metadata["frames"]`` is the number of frames, ``metadata["frame"]`` the one read."""
    path = Path(path)
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(_HEAD)
        h = parse_header(path, head, size)
        chans = []
        for i, kind in enumerate(h["kinds"][: h["channels"]]):
            name, unit = KINDS[kind]
            chans.append(Channel(name, key=(i, kind), unit=unit, extra={"code": struct.pack("<H", kind).decode()}))
        want = channel
        if isinstance(channel, str) and channel.strip().upper() in _CODES:
            code = _CODES[channel.strip().upper()]
            match = [c.name for c in chans if c.key[1] == code]
            want = match[0] if match else channel
        chan = select_channel(path, chans, want)
        k = 0 if frame is None else frame
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k < h["frames"]:
            raise ChannelNotFound(f"frame {frame!r} is not in {path}: it holds frames 0..{h['frames'] - 1}")
        index, kind = chan.key
        start = h["data_offset"] + (index * h["frames"] + int(k)) * h["frame_bytes"]
        fh.seek(start)
        fhead = fh.read(h["frame_header_size"])
        raw = fh.read(2 * h["nx"] * h["ny"])
    if len(raw) != 2 * h["nx"] * h["ny"]:
        raise CorruptScan(f"{path}: frame {k} of {chan.name} is cut (truncated file)")
    number = struct.unpack_from("<i", fhead, 0)[0] if len(fhead) >= 4 else None
    levels = np.frombuffer(raw, dtype="<i2").reshape(h["ny"], h["nx"])
    data = coefficient(path, h, kind) * levels_to_volts(levels, h["ad_range"], h["bits"])
    dx = h["x_nm"] * 1e-9 / h["nx"]
    dy = h["y_nm"] * 1e-9 / h["ny"]
    factor = 1e-9 if chan.unit == "nm" else 1.0
    return make_scan(path, FORMAT, data, dx, dy, chan, chans, rows_flipped=False, z_factor=factor,
                     z_unit="m" if chan.unit == "nm" else "deg",
                     instrument={"software": "HS-AFM (.asd)", "file_version": h["version"],
                                 "frame_time_ms": float(h["frame_time"]), "scan_direction": h["scan_direction"]},
                     extra={"frame": int(k), "frames": h["frames"], "frame_number": number,
                            "frame_time_s": float(h["frame_time"]) * 1e-3 if np.isfinite(h["frame_time"]) else None,
                            "ad_range": f"{h['ad_range']:#x}", "ad_bits": h["bits"]})
