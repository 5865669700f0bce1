"""Helpers shared by the scan-file readers: channels, units, orientation, guarded binary reads.

Every reader in :mod:`arsurf.scan.readers` returns a :class:`~arsurf.scan.scan.Scan` in the
project convention (DESIGN.md): ``heights[iy, ix]`` float64, x grows with the column, y with
the row, and **row 0 is the bottom of the image** (the smallest y), so that (x, y, z) is a
right-handed frame with z out of the sample when the image is seen from above as the
instrument software shows it. Formats that store the top row first (Gwyddion, WSxM, ASCII
matrix exports, Nanonis "down" scans) are flipped on reading; each reader module says what its
format stores.

Readers raise only :class:`arsurf.errors.ScanError` subclasses for bad files;
:func:`arsurf.scan.io.load_scan` wraps anything else a third-party parser throws.

Plausibility rules (the one place they are stated; every reader applies them through
:func:`check_shape`, :func:`check_data_size`, :func:`check_scale`, :func:`positive_length` and
:func:`make_scan`). A header field outside them is a damaged or misread file, refused with a
:class:`~arsurf.errors.CorruptScan` naming the field, never returned as a surface:

- **Image size** (:data:`MAX_PIXELS`): 1 <= nx, ny and nx * ny <= 2**28. The largest AFM
  images are 8192 x 8192 = 2**26 pixels; 2**28 float64 pixels are 2 GiB.
- **Data size against the file** (:func:`check_data_size`): the bytes a header announces must
  lie inside the file (exactly fill it where the format says so, e.g. GSF) *before* anything
  is allocated, so no allocation is sized by a header field alone: a reader's memory is a small
  multiple of the file size (the float64 copy of the stored values: 2x for float32 data, 4x for
  int16).
- **Pixel spacing** (:data:`PIXEL_RANGE`): finite, in [1e-13, 1e-3] m. 0.1 pm is a fiftieth of
  the finest STM pixel (atomic images use ~5 pm); 1 mm per pixel is ten times the widest AFM
  scanner field (~0.1 mm) spread over a single pixel. A spacing outside is a misread header
  (``dx = 1e306`` from a flipped exponent, a size in the wrong unit).
- **Z scale** (:func:`check_scale`): every scale factor a header gives (NanoScope Z scale and
  sensitivity, JPK/Nanosurf/Park gains, WSxM amplitude) finite and non-zero: a zero scale makes
  every pixel equal, an infinite or NaN one every pixel non-finite.
- **Heights** (:data:`HEIGHT_LIMIT`): a channel in metres has |z| <= 1 mm. AFM z scanners travel
  at most ~0.1 mm (100 um long-range scanners; 10-25 um is common), and the stored heights
  include the piezo offset, so 1 mm leaves a factor 10. A 16-bit integer misread as metres gives
  up to 3e4 m; float bits misread give 1e-38..1e38.
- **Units**: a channel is returned in the unit its file states (SI base unit after
  :func:`parse_unit`), never assumed to be metres when the file says otherwise or says nothing;
  ``metadata["height"]`` (:func:`height_kind`) says whether it is topography: True for a length
  unit and a height-like name, False for any other unit or for a length channel named as another
  quantity (amplitude, deflection, error, deformation...), None when a length channel's name says
  nothing (``image``, ``Channel 0``). :func:`arsurf.fit_surface` refuses ``height`` False.
"""
from __future__ import annotations

import contextlib
import logging
import math
import re
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from arsurf.errors import ChannelNotFound, CorruptScan

#: Largest image a reader accepts (pixels); a corrupt header must not make us allocate GiB.
MAX_PIXELS = 1 << 28


@dataclass
class Channel:
    """One image channel in a file, before it is read.

    Parameters
    ----------
    name : str
        The name shown to the user and listed in ``metadata["channels"]``.
    key : Any
        Whatever the reader needs to find the data again (an index, a tag, an offset).
    unit : str
        The unit of the stored values as the file writes it (``"m"``, ``"nm"``, ``"V"``...).
    direction : {"forward", "backward", None}
        Trace (forward) or retrace (backward), when the file says.
    extra : dict
        Reader-specific details.
    """

    name: str
    key: Any = None
    unit: str = ""
    direction: str | None = None
    extra: dict = field(default_factory=dict)
    height: bool | None = None

    @property
    def is_height(self) -> bool:
        """Whether the channel is topography: a length unit and a height-like name (or a reader
        that knows its format stores heights there, ``height=True``)."""
        return height_kind(self) is True


_HEIGHT_RE = re.compile(r"(^|[^a-z])(z|height|topograph|topo|zsensor)", re.IGNORECASE)
#: names of channels that hold another quantity even when their unit is a length (an amplitude
#: or a deflection in m, a Peak Force deformation, an error signal)
_NOT_HEIGHT_RE = re.compile(
    r"amplitude|phase|deflect|error|deformation|dissipation|adhesion|modulus|stiffness|current|"
    r"frequency|friction|lateral|force|potential|capacitance", re.IGNORECASE)


def height_kind(chan: "Channel") -> bool | None:
    """Whether ``chan`` is topography: True, False, or None (a length whose name says nothing).

    A reader's ``Channel(height=...)`` decides when it is set and the unit is a length; a
    non-length unit is never a height; a length channel named as another quantity
    (``AmplitudeRetrace``, ``Deformation``, ``Peak Force Error``) is not one either.

    Examples
    --------
    >>> height_kind(Channel("ZSensorRetrace", unit="m")), height_kind(Channel("AmplitudeRetrace", unit="m"))
    (True, False)
    >>> height_kind(Channel("Z", unit="V")), height_kind(Channel("image", unit="nm"))
    (False, None)
    """
    if not is_length_unit(chan.unit):
        return False
    if chan.height is not None:
        return bool(chan.height)
    if _NOT_HEIGHT_RE.search(chan.name.replace("_", " ")):
        return False
    return True if looks_like_height(chan.name) else None


#: the first 8 bytes of every HDF5 file (superblock signature)
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def h5_text(value) -> str:
    """An HDF5 attribute as text: bytes decoded as UTF-8 (undecodable bytes replaced), a
    one-element array unwrapped, anything else through ``str``."""
    if isinstance(value, (bytes, np.bytes_)):
        return bytes(value).decode("utf-8", "replace")
    if isinstance(value, np.ndarray) and value.size == 1:
        return h5_text(value.reshape(-1)[0])
    return str(value)


def open_scan_hdf5(path: Path | str, what: str):
    """Open an HDF5 scan file through :func:`arsurf._h5safe.open_hdf5` (its bytes in memory, nothing
    outside them followed, declared sizes bounded by the file), after checking the HDF5 signature;
    ``what`` names the expected format in the message. Every refusal is a :class:`CorruptScan`."""
    from arsurf._files import read_regular
    from arsurf._h5safe import open_hdf5

    data = read_regular(path, "scan file", error=CorruptScan)
    if data[:8] != HDF5_SIGNATURE:
        raise CorruptScan(f"{path}: not an HDF5 file (no HDF5 signature), so not {what}")
    try:
        return open_hdf5(data, error=CorruptScan, name=str(path))
    except OSError as exc:  # h5py's errors for a damaged file
        raise CorruptScan(f"{path}: the HDF5 structure is damaged ({str(exc).splitlines()[0]})") from None


def looks_like_height(name: str) -> bool:
    """True for channel names such as ``Z``, ``Z raw``, ``R-Z C``, ``HeightRetrace``, ``Topography``."""
    return bool(_HEIGHT_RE.search(name.replace("_", " ")))


def direction_from_name(name: str) -> str | None:
    """``"backward"`` for retrace/backward names (and neaspec's ``R-`` prefix), ``"forward"`` for trace/forward."""
    s = name.lower()
    if "retrace" in s or "backward" in s or s.startswith("r-"):
        return "backward"
    if "trace" in s or "forward" in s:
        return "forward"
    return None


_UNPRINTABLE = re.compile(r"[\x00-\x1f\x7f]")


def clean_name(name, fallback: str) -> str:
    """A channel name a user can type: cut at the first NUL (C strings padded with old bytes,
    Asylum's ``PhaseRetrace\\0race``), control characters and surrounding quotes removed,
    whitespace collapsed; ``fallback`` when nothing is left.

    Examples
    --------
    >>> clean_name('"Height"\\x00junk', "Image 0")
    'Height'
    """
    if isinstance(name, bytes):
        name = name.decode("latin-1")
    text = str(name).split("\x00", 1)[0]
    text = " ".join(_UNPRINTABLE.sub(" ", text).split())
    text = text.strip("\"'").strip()
    return text or fallback


def unique_names(channels: Sequence[Channel]) -> None:
    """Clean every channel name (:func:`clean_name`) and make it unique, in place: a repeated
    name gets `` #2``, `` #3``... in file order (JPK QI files hold two ``measuredHeight (trace)``),
    so each channel can be selected."""
    for i, c in enumerate(channels):
        c.name = clean_name(c.name, f"Channel {i}")
    seen: set[str] = set()
    for c in channels:
        name, k = c.name, 1
        while name.lower() in seen:
            k += 1
            name = f"{c.name} #{k}"
        seen.add(name.lower())
        c.name = name


def select_channel(path: Path | str, channels: Sequence[Channel], requested: str | None) -> Channel:
    """Pick the channel the user asked for, or the default topography channel.

    Default: the first height channel recorded forward (trace); else the first height channel
    without a direction; else the first height channel recorded backward (retrace); a file with a
    single channel gives that channel. A requested name is matched case-insensitively, first
    exactly, then on the name without its ``" (direction)"`` suffix when that is unique.

    Raises
    ------
    ChannelNotFound
        The name is not in the file, or no channel is topography; the message lists the channels.
    """
    if not channels:
        raise CorruptScan(f"{path}: the file holds no image channel")
    unique_names(channels)
    names = [c.name for c in channels]
    if requested is not None:
        want = str(requested).strip().lower()
        for c in channels:
            if c.name.lower() == want:
                return c
        base = [c for c in channels if c.name.split(" (")[0].lower() == want]
        if len(base) == 1:
            return base[0]
        if len(base) > 1:
            raise ChannelNotFound(
                f"channel {requested!r} is ambiguous in {path}: it matches {[c.name for c in base]}; "
                f"name one of them exactly (channels: {names})"
            )
        raise ChannelNotFound(f"channel {requested!r} is not in {path}; the channels are: {names}")
    if len(channels) == 1:
        return channels[0]
    heights = [c for c in channels if c.is_height]
    for wanted in ("forward", None, "backward"):
        for c in heights:
            if c.direction == wanted:
                return c
    raise ChannelNotFound(
        f"{path} has no height/topography channel (a length unit and a name like Z/Height/Topography); "
        f"name the one to load with channel=...; the channels are: {names}"
    )


# --------------------------------------------------------------------------------------- units
_PREFIX = {
    "Y": 1e24, "Z": 1e21, "E": 1e18, "P": 1e15, "T": 1e12, "G": 1e9, "M": 1e6, "k": 1e3,
    "h": 1e2, "da": 1e1, "d": 1e-1, "c": 1e-2, "m": 1e-3, "u": 1e-6, "\u00b5": 1e-6, "\u03bc": 1e-6,
    "~": 1e-6, "n": 1e-9, "p": 1e-12, "f": 1e-15, "a": 1e-18, "z": 1e-21, "y": 1e-24,
}
_BASE_UNITS = ("m", "V", "A", "N", "Hz", "s", "deg", "rad", "W", "F", "Pa", "S", "Ohm", "J", "%", "")
#: the electronvolt in joules (exact since the 2019 SI redefinition; CODATA 2018)
ELECTRONVOLT = 1.602176634e-19


def parse_unit(unit: str) -> tuple[float, str]:
    """Split a unit string into (factor to SI, SI base unit): ``"nm" -> (1e-9, "m")``.

    Handles the SI prefixes, ``µ``/``u``/``~`` for micro (NanoScope writes ``~m``), ``Å``,
    electronvolts (``eV``, ``meV``... -> J, :data:`ELECTRONVOLT`), ``um``-style spellings and a
    leading power of ten (``"1e-9 m"``). Unknown units (``Arb``) come back with factor 1 and the
    string unchanged.

    Examples
    --------
    >>> parse_unit("~m")
    (1e-06, 'm')
    """
    u = (unit or "").strip()
    factor = 1.0
    m = re.match(r"^([-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?)\s*(.*)$", u)
    if m and m.group(2):
        factor = float(m.group(1))
        u = m.group(2).strip()
    if u in ("\u00c5", "\u212b", "Angstrom", "angstrom", "Ang"):
        return factor * 1e-10, "m"
    if u in ("deg", "\u00b0", "\u00ba", "degree", "degrees"):
        return factor, "deg"
    if u in _BASE_UNITS or u in ("Ohm",):
        return factor, u
    if u.endswith("eV") and (u == "eV" or u[:-2] in _PREFIX):
        return factor * _PREFIX.get(u[:-2], 1.0) * ELECTRONVOLT, "J"
    for base in ("Hz", "Pa", "Ohm", "rad", "m", "V", "A", "N", "s", "W", "F", "S", "J"):
        if u.endswith(base) and len(u) > len(base):
            prefix = u[: -len(base)]
            if prefix in _PREFIX:
                return factor * _PREFIX[prefix], base
    return factor, u


def is_length_unit(unit: str) -> bool:
    """True when the unit is a length (m with any prefix, Å)."""
    return parse_unit(unit)[1] == "m"


# ------------------------------------------------------------------------------ binary helpers
def check_shape(path: Path | str, nx: int, ny: int) -> None:
    """Reject non-positive or absurd image sizes read from a header."""
    if not (isinstance(nx, (int, np.integer)) and isinstance(ny, (int, np.integer))):
        raise CorruptScan(f"{path}: image size is not an integer ({nx!r} x {ny!r})")
    if nx < 1 or ny < 1 or nx * ny > MAX_PIXELS:
        raise CorruptScan(
            f"{path}: the header gives an image of {nx} x {ny} pixels, which is not a valid size "
            "(truncated or corrupt header)"
        )


def take(path: Path | str, buf: bytes | memoryview, offset: int, nbytes: int, what: str) -> memoryview:
    """``buf[offset:offset+nbytes]`` or :class:`CorruptScan` saying the file is too short."""
    if offset < 0 or nbytes < 0 or offset + nbytes > len(buf):
        raise CorruptScan(
            f"{path}: {what} needs bytes {offset}..{offset + nbytes} but the file has {len(buf)} bytes "
            "(truncated or corrupt file)"
        )
    return memoryview(buf)[offset : offset + nbytes]


def frombuffer(path, buf, offset: int, dtype, count: int, what: str) -> np.ndarray:
    """A bounds-checked ``np.frombuffer`` returning a float64 copy."""
    dt = np.dtype(dtype)
    raw = take(path, buf, offset, dt.itemsize * count, what)
    with np.errstate(invalid="ignore"):  # signalling-NaN payloads of damaged floats
        return np.frombuffer(raw, dtype=dt, count=count).astype(np.float64)


def parse_float(path, text: str, what: str) -> float:
    """``float(text)`` or :class:`CorruptScan` naming the field."""
    try:
        value = float(str(text).strip().replace(",", "."))
    except (TypeError, ValueError):
        raise CorruptScan(f"{path}: {what} is not a number (got {text!r})") from None
    return value


def parse_int(path, text: str, what: str) -> int:
    """``int(text)`` or :class:`CorruptScan` naming the field."""
    try:
        return int(str(text).strip())
    except (TypeError, ValueError):
        try:
            f = float(str(text).strip())
        except (TypeError, ValueError):
            raise CorruptScan(f"{path}: {what} is not an integer (got {text!r})") from None
        if not f.is_integer():
            raise CorruptScan(f"{path}: {what} is not an integer (got {text!r})") from None
        return int(f)


#: plausible AFM pixel spacings, metres (module docstring: "Plausibility rules")
PIXEL_RANGE = (1e-13, 1e-3)
#: largest plausible |height| of a channel in metres (module docstring: "Plausibility rules")
HEIGHT_LIMIT = 1e-3


def check_data_size(path, available: int, needed: int, what: str, exact: bool = False) -> None:
    """Refuse a header whose data do not fit in the file (or, with ``exact``, do not fill it
    exactly, where the format says so), before anything is allocated from it.

    Examples
    --------
    >>> check_data_size("f.gsf", 100, 96, "4 x 6 float32 pixels", exact=True)
    Traceback (most recent call last):
    ...
    arsurf.errors.CorruptScan: f.gsf: 4 x 6 float32 pixels need 96 bytes of data but the file holds 100; the header's image size does not match the data (corrupt header or file)
    """
    if needed < 0 or needed > available or (exact and needed != available):
        short = needed > available
        raise CorruptScan(
            f"{path}: {what} need {needed} bytes of data but the file holds {available}; "
            + ("the file is truncated or the header's image size is wrong" if short
               else "the header's image size does not match the data (corrupt header or file)")
        )


def check_scale(path, value, what: str) -> float:
    """A scale factor from a header (a gain, a Z scale, a sensitivity): finite and non-zero,
    else :class:`CorruptScan` naming ``what`` (zero would make every pixel equal)."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise CorruptScan(f"{path}: {what} is not a number ({value!r}); the header is damaged") from None
    if not (math.isfinite(v) and v != 0.0):
        raise CorruptScan(f"{path}: {what} is {v!r}: a z scale must be finite and non-zero (every value would be "
                          "0 or NaN); the header is damaged")
    return v


def positive_length(path, value: float, what: str) -> float:
    """Check a pixel spacing read from a header: finite and within :data:`PIXEL_RANGE`."""
    v = float(value)
    if not (np.isfinite(v) and v > 0.0):
        raise CorruptScan(f"{path}: {what} must be a positive length (got {value!r})")
    if not (PIXEL_RANGE[0] <= v <= PIXEL_RANGE[1]):
        raise CorruptScan(f"{path}: {what} is {v:g} m, outside any AFM's range [{PIXEL_RANGE[0]:g}, "
                          f"{PIXEL_RANGE[1]:g}] m; the header is damaged or misread")
    return v


def tiff_first_ifd_tags(head: bytes) -> dict[int, tuple[int, int, bytes]]:
    """Tags of the first TIFF directory found in ``head``: ``{code: (type, count, 4 value bytes)}``.

    Only classic TIFF; returns ``{}`` when ``head`` is not a TIFF or the directory lies past it.
    Used by the sniffers to tell JPK and Park TIFFs apart without a TIFF library.
    """
    if len(head) < 8 or head[:4] not in (b"II*\x00", b"MM\x00*"):
        return {}
    bo = "<" if head[:2] == b"II" else ">"
    (off,) = struct.unpack(bo + "I", head[4:8])
    if off + 2 > len(head):
        return {}
    (n,) = struct.unpack(bo + "H", head[off : off + 2])
    tags = {}
    for i in range(n):
        p = off + 2 + 12 * i
        if p + 12 > len(head):
            break
        code, typ, count = struct.unpack(bo + "HHI", head[p : p + 8])
        tags[code] = (typ, count, head[p + 8 : p + 12])
    return tags


def flip_rows(a: np.ndarray) -> np.ndarray:
    """Reverse the row order (top-first storage -> row 0 at the bottom)."""
    return np.ascontiguousarray(a[::-1, :])


def jsonable(value: Any) -> Any:
    """Metadata values made JSON-friendly (numpy scalars/arrays, bytes, tuples)."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, bytes):
        return value.decode("latin-1")
    if isinstance(value, float) or isinstance(value, (int, str, bool)) or value is None:
        return value
    return str(value)


def make_scan(
    path: Path | str,
    fmt: str,
    data: np.ndarray,
    dx: float,
    dy: float,
    chan: Channel,
    channels: Sequence[Channel],
    *,
    rows_flipped: bool,
    z_factor: float | None = None,
    z_unit: str | None = None,
    instrument: dict | None = None,
    extra: dict | None = None,
):
    """Build the :class:`Scan` a reader returns, with the metadata every reader fills.

    ``data`` is the channel in file units, already in the project orientation (row 0 = bottom).
    It is multiplied by ``z_factor`` (default: the SI factor of ``chan.unit``), infinite pixels
    become NaN (missing), and ``metadata`` gets ``format``, ``channels``, ``channel_units``
    (each channel's SI unit, as the reader knows it before reading), ``direction``,
    ``z_unit``, ``height`` (:func:`height_kind`), ``rows_flipped``, ``row0`` (always
    ``"bottom"``), ``nan_count`` and ``instrument``. The plausibility rules of the module
    docstring are applied here (z scale, heights of a length channel, pixel spacings).
    """
    from arsurf.scan.scan import Scan

    if z_factor is None:
        z_factor, base = parse_unit(chan.unit)
        z_unit = base if z_unit is None else z_unit
    z_factor = check_scale(path, z_factor, f"the z scale of channel {chan.name!r}")
    with np.errstate(invalid="ignore", over="ignore"):  # damaged floats: NaN/inf are counted below
        h = np.asarray(data, dtype=np.float64) * float(z_factor)
    if h.ndim != 2:
        raise CorruptScan(f"{path}: channel {chan.name!r} is not a 2-D image (shape {h.shape})")
    bad = ~np.isfinite(h)
    inf_count = int(np.isinf(h).sum())
    if inf_count:
        h = np.where(np.isinf(h), np.nan, h)
    unit = z_unit if z_unit is not None else parse_unit(chan.unit)[1]
    if unit == "m":
        with np.errstate(invalid="ignore"):
            top = float(np.nanmax(np.abs(h))) if h.size and not np.isnan(h).all() else 0.0
        if top > HEIGHT_LIMIT:
            raise CorruptScan(f"{path}: channel {chan.name!r} has heights up to {top:g} m, more than any AFM's z "
                              f"travel ({HEIGHT_LIMIT:g} m); its z scale is damaged or misread")
    dx = positive_length(path, dx, "the x pixel spacing")
    dy = positive_length(path, dy, "the y pixel spacing")
    meta: dict[str, Any] = {
        "format": fmt,
        "channels": [c.name for c in channels],
        "channel_units": {c.name: parse_unit(c.unit)[1] for c in channels},
        "direction": chan.direction,
        "z_unit": unit,
        "height": height_kind(Channel(chan.name, unit=unit, height=chan.height)),
        "file_z_unit": chan.unit,
        "row0": "bottom",
        "rows_flipped": bool(rows_flipped),
        "nan_count": int(bad.sum()),
        "inf_count": inf_count,
        "instrument": jsonable(instrument or {}),
    }
    if extra:
        meta.update(jsonable(extra))
    return Scan(h, dx=dx, dy=dy, channel=chan.name, metadata=meta, source=str(path))


@contextlib.contextmanager
def quiet_logger(name: str):
    """Silence a library's logger for the duration (restores its level after).

    tifffile and igor2 log every defect of a damaged file (igor2 logs the whole data buffer);
    the reader turns those defects into one :class:`CorruptScan` instead.
    """
    logger = logging.getLogger(name)
    old = logger.level
    logger.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        logger.setLevel(old)


def check_tiff_chain(path, filename) -> None:
    """Walk the directory chain of a classic TIFF and raise :class:`CorruptScan` if it is cut.

    tifffile stops quietly at a directory offset past the end of a truncated file and returns
    the pages before it, so a truncated multi-page file would silently lose channels.
    """
    with open(filename, "rb") as fh:
        buf = fh.read()
    if len(buf) < 8 or buf[:4] not in (b"II*\x00", b"MM\x00*"):
        raise CorruptScan(f"{path}: not a classic TIFF file")
    bo = "<" if buf[:2] == b"II" else ">"
    (off,) = struct.unpack(bo + "I", buf[4:8])
    seen = set()
    while off:
        if off in seen or len(seen) > 100000:
            raise CorruptScan(f"{path}: the TIFF directory chain loops (corrupt file)")
        seen.add(off)
        if off + 2 > len(buf):
            raise CorruptScan(f"{path}: TIFF directory at byte {off} lies past the end ({len(buf)} bytes; truncated)")
        (n,) = struct.unpack(bo + "H", buf[off : off + 2])
        end = off + 2 + 12 * n + 4
        if end > len(buf):
            raise CorruptScan(f"{path}: TIFF directory at byte {off} runs past the end of the file (truncated)")
        (off,) = struct.unpack(bo + "I", buf[end - 4 : end])
