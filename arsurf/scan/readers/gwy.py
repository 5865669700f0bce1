"""Gwyddion native ``.gwy`` reader and writer.

Library: our own bounds-checked parser of the GWY serialisation, cross-checked against
``gwyfile`` on the real 58-channel file in the tests (every channel identical).
Why not ``gwyfile.load``: it is correct on good files but not on damaged ones. A string
array (type ``S``) takes its item count from the file and, once past the end of the buffer,
``buf.find`` returns -1 and the loop restarts at offset 0: it then either loops up to that count
(2**32 at worst) or fails with an unrelated ``UnicodeDecodeError``; a single flipped bit turns a
string ``s`` into ``S`` (0x73 -> 0x53), which we checked on the real file. It also copies the
remaining buffer at every component (``buf[component_size:]``), quadratic in the file size.

Format (gwyddion.net, "Gwyddion native file format"): magic ``GWYP``, then one serialised
object: ``name\\0``, uint32 size, components; a component is ``name\\0``, a type character and
its data (``b c i q d s o`` scalars and ``C I Q D S O`` arrays with a uint32 count).
Images are ``GwyDataField`` objects stored under ``/N/data`` with titles ``/N/data/title``.

Orientation: Gwyddion's row 0 is the top of the image (y grows down the screen), so rows are
flipped on reading: row 0 = bottom, y up. Pixel spacing ``dx = xreal / xres``.
Units: ``si_unit_xy`` / ``si_unit_z`` strings with optional prefixes (``nm``) are honoured.
"""
from __future__ import annotations

import re
import struct
from pathlib import Path

import numpy as np

from arsurf._files import atomic_write
from arsurf.errors import CorruptScan, ScanError, UnsupportedScan
from arsurf.scan.readers._common import (
    Channel,
    check_shape,
    direction_from_name,
    flip_rows,
    make_scan,
    parse_unit,
    positive_length,
    select_channel,
)

MAGIC = b"GWYP"
EXTENSIONS = (".gwy",)
FORMAT = "gwy"
_MAX_DEPTH = 64
_SCALAR = {"b": 1, "c": 1, "i": 4, "q": 8, "d": 8}
_ARRAY = {"C": "u1", "I": "<i4", "Q": "<i8", "D": "<f8"}


#: magic of Gwyddion 1.x files (an older serialisation, not read: refused with a plain message)
MAGIC_V1 = b"GWYO"


def sniff(head: bytes) -> bool:
    """True when the file starts with ``GWYP`` (or 1.x's ``GWYO``) followed by an object name."""
    return head.startswith((MAGIC, MAGIC_V1)) and head[4:5].isalpha()


class _Parser:
    """Offsets-based GWY deserialiser: every length is checked against the object's end."""

    def __init__(self, path, buf: bytes):
        self.path = path
        self.buf = buf

    def fail(self, msg: str):
        raise CorruptScan(f"{self.path}: corrupt GWY file: {msg}")

    def cstring(self, pos: int, end: int) -> tuple[str, int]:
        nul = self.buf.find(b"\x00", pos, end)
        if nul < 0:
            self.fail(f"unterminated string at byte {pos}")
        return self.buf[pos:nul].decode("utf-8", errors="replace"), nul + 1

    def obj(self, pos: int, end: int, depth: int) -> tuple[dict, int]:
        if depth > _MAX_DEPTH:
            self.fail("objects nested too deeply")
        name, pos = self.cstring(pos, end)
        if pos + 4 > end:
            self.fail(f"object {name!r} has no size")
        (size,) = struct.unpack_from("<I", self.buf, pos)
        pos += 4
        stop = pos + size
        if stop > end:
            self.fail(f"object {name!r} claims {size} bytes past the end of its container")
        out: dict = {"__type__": name}
        while pos < stop:
            key, pos = self.cstring(pos, stop)
            if pos >= stop:
                self.fail(f"component {key!r} has no type")
            t = chr(self.buf[pos])
            pos += 1
            out[key], pos = self.value(t, pos, stop, depth)
        return out, stop

    def value(self, t: str, pos: int, stop: int, depth: int):
        buf = self.buf
        if t in _SCALAR:
            n = _SCALAR[t]
            if pos + n > stop:
                self.fail(f"scalar of type {t!r} runs past its object")
            fmt = {"b": "<B", "c": "<c", "i": "<i", "q": "<q", "d": "<d"}[t]
            (v,) = struct.unpack_from(fmt, buf, pos)
            return (bool(v) if t == "b" else v), pos + n
        if t == "s":
            return self.cstring(pos, stop)
        if t == "o":
            return self.obj(pos, stop, depth + 1)
        if t in _ARRAY or t in "SO":
            if pos + 4 > stop:
                self.fail(f"array of type {t!r} has no length")
            (count,) = struct.unpack_from("<I", buf, pos)
            pos += 4
            if t in _ARRAY:
                dt = np.dtype(_ARRAY[t])
                nbytes = count * dt.itemsize
                if pos + nbytes > stop:
                    self.fail(f"array of {count} items of type {t!r} runs past its object")
                return np.frombuffer(buf, dtype=dt, count=count, offset=pos), pos + nbytes
            # every string takes >= 1 byte and every object >= 6: bound the loop by the bytes left
            if count > (stop - pos):
                self.fail(f"array of {count} items of type {t!r} cannot fit in {stop - pos} bytes")
            items = []
            for _ in range(count):
                if t == "S":
                    item, pos = self.cstring(pos, stop)
                else:
                    item, pos = self.obj(pos, stop, depth + 1)
                items.append(item)
            return items, pos
        self.fail(f"unknown component type {t!r} at byte {pos - 1}")


def parse(path, buf: bytes) -> dict:
    """The top-level object of a GWY file as nested dicts (arrays as read-only numpy views)."""
    if buf.startswith(MAGIC_V1):
        raise UnsupportedScan(f"{path}: a Gwyddion 1.x file (GWYO magic), an older format that arsurf does not read; "
                          "open it in Gwyddion 2 and save it again (as .gwy or .gsf)")
    if not buf.startswith(MAGIC):
        raise CorruptScan(f"{path}: missing the GWYP magic bytes")
    top, _ = _Parser(path, buf).obj(4, len(buf), 0)
    return top


def _unit(field: dict, key: str) -> str:
    u = field.get(key)
    if isinstance(u, dict):
        s = u.get("unitstr", "")
        return s if isinstance(s, str) else ""
    return ""


def _channels(path, top: dict) -> list[Channel]:
    chans = []
    ids = sorted(
        int(m.group(1)) for k in top if (m := re.fullmatch(r"/(\d+)/data", k)) and isinstance(top[k], dict)
    )
    seen: dict[str, int] = {}
    for i in ids:
        field = top[f"/{i}/data"]
        if field.get("__type__") != "GwyDataField":
            continue
        title = top.get(f"/{i}/data/title")
        title = title if isinstance(title, str) and title else f"Channel {i}"
        if title in seen:  # keep names unique so that each can be asked for
            title = f"{title} [{i}]"
        seen[title] = i
        chans.append(Channel(title, key=i, unit=_unit(field, "si_unit_z"), direction=direction_from_name(title)))
    return chans


def read(path: Path | str, channel: str | None = None):
    """Read one channel of a ``.gwy`` file (default: the first forward height channel).

    Examples
    --------
    >>> scan = read("waveguide.gwy", channel="Z raw")  # doctest: +SKIP
    """
    buf = Path(path).read_bytes()
    top = parse(path, buf)
    chans = _channels(path, top)
    chan = select_channel(path, chans, channel)
    field = top[f"/{chan.key}/data"]
    try:
        nx, ny = int(field["xres"]), int(field["yres"])
        data = field["data"]
    except (KeyError, TypeError, ValueError):
        raise CorruptScan(f"{path}: data field {chan.name!r} lacks xres/yres/data") from None
    check_shape(path, nx, ny)
    if not isinstance(data, np.ndarray) or data.size != nx * ny:
        raise CorruptScan(
            f"{path}: data field {chan.name!r} holds {getattr(data, 'size', 0)} values, not xres*yres = {nx * ny}"
        )
    xy_factor, xy_base = parse_unit(_unit(field, "si_unit_xy") or "m")
    if xy_base != "m":
        raise CorruptScan(f"{path}: lateral unit {_unit(field, 'si_unit_xy')!r} of {chan.name!r} is not a length")
    xreal = positive_length(path, float(field.get("xreal", 1.0)) * xy_factor, "xreal")
    yreal = positive_length(path, float(field.get("yreal", 1.0)) * xy_factor, "yreal")
    meta = top.get(f"/{chan.key}/meta")
    meta = {k: v for k, v in meta.items() if k != "__type__" and isinstance(v, (str, int, float))} if isinstance(meta, dict) else {}
    img = np.asarray(data, dtype=np.float64).reshape(ny, nx)
    mask = top.get(f"/{chan.key}/mask")
    if meta.get(_MISSING_KEY) == f"/{chan.key}/mask" and isinstance(mask, dict) and \
            isinstance(mask.get("data"), np.ndarray) and mask["data"].size == nx * ny:
        img = np.where(np.asarray(mask["data"]).reshape(ny, nx) > 0.5, np.nan, img)  # written by arsurf
    return make_scan(
        path, FORMAT, flip_rows(img), xreal / nx, yreal / ny, chan, chans, rows_flipped=True,
        instrument=meta,
        extra={"xoff": float(field.get("xoff", 0.0)) * xy_factor, "yoff": float(field.get("yoff", 0.0)) * xy_factor},
    )


# ---------------------------------------------------------------------------------------------
# writing


def _component(name: str, kind: str, payload: bytes) -> bytes:
    return name.encode("utf-8") + b"\0" + kind.encode() + payload


def _string(text: str) -> bytes:
    return str(text).replace("\0", "").encode("utf-8") + b"\0"


def _object(type_name: str, components: list[bytes]) -> bytes:
    body = b"".join(components)
    return type_name.encode() + b"\0" + struct.pack("<I", len(body)) + body


def _si_unit(unit: str) -> bytes:
    return _object("GwySIUnit", [_component("unitstr", "s", _string(unit))])


def _data_field(values: np.ndarray, dx: float, dy: float, z_unit: str) -> bytes:
    ny, nx = values.shape
    data = np.ascontiguousarray(values, dtype="<f8")
    return _object("GwyDataField", [
        _component("xres", "i", struct.pack("<i", nx)),
        _component("yres", "i", struct.pack("<i", ny)),
        _component("xreal", "d", struct.pack("<d", nx * dx)),
        _component("yreal", "d", struct.pack("<d", ny * dy)),
        _component("si_unit_xy", "o", _si_unit("m")),
        _component("si_unit_z", "o", _si_unit(z_unit)),
        _component("data", "D", struct.pack("<I", data.size) + data.tobytes()),
    ])


#: /N/meta key by which arsurf marks its mask as "missing pixels" (read back as NaN)
_MISSING_KEY = "arsurf missing pixels"


def write(scan, path: Path | str) -> None:
    """Write ``scan`` as a Gwyddion ``.gwy`` file (channel 0), so a processed or deformed surface
    opens in Gwyddion with its calibration.

    The data field holds the heights in the scan's unit (metadata ``z_unit``, default ``m``) with
    ``xreal = nx dx``, ``yreal = ny dy`` in metres, rows in Gwyddion's top-first order; NaN
    pixels are written as 0 and marked in a mask field ``/0/mask`` (1 = missing), Gwyddion's
    way; the channel name is the title and the scan's processing history and source go to
    ``/0/meta`` as text.
    """
    ny, nx = scan.shape
    z_unit = str(scan.metadata.get("z_unit") or "m")
    top = np.ascontiguousarray(scan.heights[::-1, :], dtype=np.float64)
    missing = ~np.isfinite(top)
    components = [
        _component("/0/data", "o", _data_field(np.where(missing, 0.0, top), scan.dx, scan.dy, z_unit)),
        _component("/0/data/title", "s", _string(scan.channel or "Height")),
    ]
    if missing.any():
        components.append(_component("/0/mask", "o", _data_field(missing.astype(np.float64), scan.dx, scan.dy, "")))
    meta = {"arsurf source": str(scan.source or ""),
            "arsurf history": "; ".join(str(h) for h in scan.metadata.get("history", []))}
    if missing.any():
        meta[_MISSING_KEY] = "/0/mask"
    components.append(_component("/0/meta", "o", _object(
        "GwyContainer", [_component(k, "s", _string(v)) for k, v in meta.items()])))
    with atomic_write(path, what="scan file", error=ScanError) as fh:
        fh.write(MAGIC + _object("GwyContainer", components))
