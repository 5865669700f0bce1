"""NumPy ``.npz`` reader and writer (arsurf's own lossless format).

Library: numpy (``np.load(..., allow_pickle=False)``; no unpickling).

:func:`write` stores ``heights`` (float64 metres, row 0 = bottom, as in the Scan) and
``arsurf_meta``, a 0-d unicode array holding JSON with ``dx``, ``dy``, ``channel``, ``source``
and the metadata: the round trip is bit-exact for the heights and the spacings, and the
metadata come back as their JSON form (tuples become lists, numpy scalars plain numbers).
Other ``.npz`` files are read too: every 2-D numeric array is a channel (``heights`` or the
first one by default), ``dx``/``dy`` entries give the spacing, else pass ``dx``/``dy``/``z_unit``;
``arsurf_meta`` may state ``z_unit`` for the file or ``units`` per array (``{"Height": "m"}``).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from arsurf._files import atomic_write
from arsurf.errors import CorruptScan, ScanError, UnsupportedScan
from arsurf.scan.readers._common import Channel, select_channel
from arsurf.scan.readers.npy import finish, header_info

EXTENSIONS = (".npz",)
FORMAT = "npz"


def sniff(head: bytes) -> bool:
    """True for a ZIP archive whose first member is a ``.npy`` array."""
    if not head.startswith(b"PK\x03\x04") or len(head) < 30:
        return False
    n = int.from_bytes(head[26:28], "little")
    return head[30 : 30 + n].endswith(b".npy")


def read(path: Path | str, channel: str | None = None, *, dx: float | None = None,
         dy: float | None = None, z_unit: str | None = None):
    """Read a channel of a ``.npz`` (default ``heights``)."""
    with np.load(str(path), allow_pickle=False) as z:
        info: dict = {}
        if "arsurf_meta" in z.files:
            try:
                info = json.loads(str(z["arsurf_meta"][()]))
            except ValueError as exc:
                raise CorruptScan(f"{path}: arsurf_meta is not valid JSON ({exc})") from None
            if not isinstance(info, dict):
                raise CorruptScan(f"{path}: arsurf_meta does not hold a JSON object")
        for key in ("dx", "dy"):
            if key in z.files and key not in info:
                info[key] = float(np.asarray(z[key]).reshape(-1)[0])
        names = [n for n in z.files if n not in ("arsurf_meta", "dx", "dy")]
        images = []
        for n in names:
            a = z[n]
            if a.ndim == 2 and a.dtype.kind in "fiub":
                images.append(n)
        if not images and {"control_points", "knots_u", "knots_v", "metadata_json"} <= set(z.files):
            raise UnsupportedScan(f"{path}: a fitted surface (`arsurf fit` output), not a scan; `arsurf info` "
                                  "describes it, `arsurf export SURFACE -o heights.gsf` samples it as a height map")
        if not images:
            raise CorruptScan(f"{path}: no 2-D numeric array in the archive (entries: {z.files})")
        chans = [Channel(n, key=n, unit="m", direction=None) for n in images]
        if channel is None:
            key = "heights" if "heights" in images else images[0]
        else:
            key = select_channel(path, chans, channel).name
        data = z[key]
    units = info.get("units")
    if isinstance(units, dict):  # per-array units ({"Height": "m", "DMTModulus": "Pa"}): this array's
        info = {k: v for k, v in info.items() if k not in ("units", "z_unit")}
        if isinstance(units.get(key), str):
            info["z_unit"] = units[key]
    if key == "heights" and "channel" in info:
        return finish(path, FORMAT, data, info, None, dx, dy, z_unit)
    info = {k: v for k, v in info.items() if k != "channel"}
    return finish(path, FORMAT, data, info, None, dx, dy, z_unit, names=images, key=key)


def write(scan, path: Path | str) -> None:
    """Write ``heights`` and the ``arsurf_meta`` JSON (bit-exact round trip)."""
    meta = json.dumps(header_info(scan), allow_nan=True)
    with atomic_write(path, what="scan file", error=ScanError) as fh:
        np.savez(fh, heights=np.asarray(scan.heights, dtype=np.float64), arsurf_meta=np.array(meta))
