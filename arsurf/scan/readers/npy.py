"""NumPy ``.npy`` reader and writer (arsurf's own plain-array exchange).

Library: numpy (``np.load(..., allow_pickle=False)``): never unpickles, so a hostile file
cannot run code.

A ``.npy`` holds only the array. :func:`write` stores ``heights`` (float64 metres, row 0 =
bottom, exactly as in the :class:`~arsurf.scan.scan.Scan`) and a sidecar ``<file>.npy.json``
with ``dx_m``, ``dy_m`` (``dx``, ``dy`` in files written before the unit was in the key, still
read), ``channel``, ``source`` and the metadata, so the round trip is bit-exact.
A ``.npy`` from elsewhere, without the sidecar, needs ``dx``/``dy`` (m) and ``z_unit`` passed
to :func:`arsurf.load_scan`; otherwise :class:`MissingCalibration` is raised.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from arsurf._files import atomic_write, write_text
from arsurf.errors import CorruptScan, ScanError
from arsurf.scan.readers._common import Channel, check_shape, jsonable, make_scan, select_channel
from arsurf.errors import MissingCalibration

EXTENSIONS = (".npy",)
FORMAT = "npy"
MAGIC = b"\x93NUMPY"


def sniff(head: bytes) -> bool:
    """True for the ``\\x93NUMPY`` magic."""
    return head.startswith(MAGIC)


def sidecar(path: Path | str) -> Path:
    """The JSON file that carries the spacing and metadata of ``path``."""
    return Path(str(path) + ".json")


def read_sidecar(path, side: Path) -> dict:
    try:
        info = json.loads(side.read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise CorruptScan(f"{path}: its sidecar {side.name} is not valid JSON ({exc})") from None
    if not isinstance(info, dict):
        raise CorruptScan(f"{path}: its sidecar {side.name} does not hold a JSON object")
    for key in ("dx", "dy"):  # the spacing is stored as dx_m, dy_m (arsurf.units); files before that say dx, dy
        if f"{key}_m" in info:
            info[key] = info.pop(f"{key}_m")
    return info


def finish(path, fmt, data, info: dict, channel, dx, dy, z_unit, names=None, key=None):
    """Common end of the npy/npz readers: spacing from the sidecar/meta or the arguments."""
    if not (isinstance(data, np.ndarray) and data.ndim == 2 and data.dtype.kind in "fiub"):
        raise CorruptScan(f"{path}: the array is not a 2-D numeric image (shape {getattr(data, 'shape', None)})")
    ny, nx = data.shape
    check_shape(path, nx, ny)
    meta = info.get("metadata") if isinstance(info.get("metadata"), dict) else {}
    for field, given in (("dx", dx), ("dy", dy), ("z_unit", z_unit)):
        stated = meta.get(field, info.get(field)) if field == "z_unit" else info.get(field)
        if given is not None and stated is not None and given != stated:
            raise ScanError(f"{path}: the file states {field} = {stated!r}; {field}={given!r} (CLI: --dx-nm/--dy-nm/"
                            "--z-unit) applies only to arrays that do not state it: remove it")
    dx = dx if dx is not None else info.get("dx")
    dy = dy if dy is not None else info.get("dy")
    if dx is None or dy is None:
        raise MissingCalibration(
            f"{path} holds a bare array without pixel spacing; pass it in metres, "
            "e.g. load_scan(path, dx=1e-8, dy=1e-8, z_unit='m') (arsurf CLI: --dx-nm 10 --dy-nm 10 --z-unit m), "
            "or save with arsurf.save_scan"
        )
    unit = z_unit
    if unit is None and isinstance(info.get("metadata"), dict):
        unit = info["metadata"].get("z_unit")
    if unit is None:
        unit = info.get("z_unit")
    if unit is None:
        raise MissingCalibration(f"{path} does not say the unit of its values; pass z_unit, e.g. z_unit='m' (CLI: --z-unit m)")
    try:
        dx, dy = float(dx), float(dy)
    except (TypeError, ValueError):
        raise CorruptScan(f"{path}: dx/dy are not numbers ({dx!r}, {dy!r})") from None
    name = str(info.get("channel", key or "Height"))
    chans = [Channel(n, key=n, unit=unit) for n in (names or [name])]
    if names is None:
        chan = select_channel(path, chans, channel)
    else:
        chan = next(c for c in chans if c.name == key)
    scan = make_scan(path, fmt, data.astype(np.float64), dx, dy, chan, chans, rows_flipped=False)
    meta = info.get("metadata")
    if isinstance(meta, dict):  # our own file: restore its metadata as saved (format = this file's)
        restored = dict(meta)
        restored["format"] = fmt
        restored["nan_count"] = scan.metadata["nan_count"]
        return type(scan)(scan.heights, dx=scan.dx, dy=scan.dy, channel=chan.name, metadata=restored,
                          source=str(path))
    return scan


def read(path: Path | str, channel: str | None = None, *, dx: float | None = None,
         dy: float | None = None, z_unit: str | None = None):
    """Read a ``.npy`` height array (with its sidecar JSON when there is one)."""
    data = np.load(str(path), allow_pickle=False)
    side = sidecar(path)
    info = read_sidecar(path, side) if side.exists() else {}
    return finish(path, FORMAT, data, info, channel, dx, dy, z_unit)


def header_info(scan) -> dict:
    """What the sidecar (npy) or the ``arsurf_meta`` entry (npz) stores besides the heights."""
    return {"dx": scan.dx, "dy": scan.dy, "channel": scan.channel, "source": scan.source,
            "z_unit": str(scan.metadata.get("z_unit") or "m"), "metadata": jsonable(scan.metadata)}


def write(scan, path: Path | str) -> None:
    """Write ``scan.heights`` (float64, bit-exact) and the ``.npy.json`` sidecar."""
    with atomic_write(path, what="scan file", error=ScanError) as fh:
        np.save(fh, np.asarray(scan.heights, dtype=np.float64), allow_pickle=False)
    info = header_info(scan)
    info = {"dx_m": info.pop("dx"), "dy_m": info.pop("dy"), **info}  # the unit in the key, as every JSON we write
    write_text(sidecar(path), json.dumps(info, allow_nan=True), what="scan sidecar", error=ScanError)
