"""ASCII XYZ reader (``.xyz``, or a 3-column text table): one ``x y z`` point per line.

Library: our own (numpy). The points must lie on a regular grid (as Gwyddion's XYZ export and
most instrument "XYZ" exports write them, in any order); scattered points are refused rather
than interpolated, because interpolation is a processing choice, not reading.

Units: x, y and z are taken as metres (Gwyddion's XYZ export writes SI base units); pass
``xy_unit`` and/or ``z_unit`` (e.g. ``"nm"``) to :func:`arsurf.load_scan` for other exports.
Orientation: the coordinates are explicit: column ix has x = x_min + ix*dx and row iy has
y = y_min + iy*dy, so y grows with the row and row 0 is the smallest y (no flip).
Grid points absent from the file become NaN (counted in ``metadata["nan_count"]``).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from arsurf.errors import CorruptScan
from arsurf.scan.readers._common import Channel, check_shape, make_scan, parse_unit, select_channel
from arsurf.scan.readers.ascii_matrix import _numeric_rows, sniff_columns

EXTENSIONS = (".xyz",)
FORMAT = "xyz"


def sniff(head: bytes) -> bool:
    """True for a 3-column numeric table whose first two columns repeat (a grid of points)."""
    if sniff_columns(head) != 3:
        return False
    _, rows = _numeric_rows(head.decode("latin-1"), limit=64)
    xs = [r[0] for r in rows]
    ys = [r[1] for r in rows]
    return len(rows) >= 4 and (len(set(xs)) < len(xs) or len(set(ys)) < len(ys))


def _axis(path, v: np.ndarray, name: str) -> tuple[np.ndarray, float, float]:
    """Grid index of every coordinate, the origin and the spacing of one axis."""
    u = np.unique(v)
    if u.size == 1:
        raise CorruptScan(f"{path}: all points have the same {name}; an image needs at least 2 distinct {name} values")
    step = float(np.min(np.diff(u)))
    idx = (v - u[0]) / step
    k = np.rint(idx)
    if np.max(np.abs(idx - k)) > 1e-3:
        raise CorruptScan(
            f"{path}: the {name} coordinates are not on a regular grid (spacing {step:g}); "
            "grid the points first (e.g. scipy.interpolate.griddata)"
        )
    return k.astype(np.int64), float(u[0]), step


def read(path: Path | str, channel: str | None = None, *, xy_unit: str | None = None, z_unit: str | None = None):
    """Read gridded XYZ points into a height map (x, y in ``xy_unit``, z in ``z_unit``; default m)."""
    text = Path(path).read_bytes().decode("utf-8", errors="replace")
    _, rows = _numeric_rows(text)
    if not rows or any(len(r) != 3 for r in rows):
        raise CorruptScan(f"{path}: every line of an XYZ file must hold exactly 3 numbers")
    try:
        pts = np.array(rows, dtype=np.float64)
    except ValueError:
        raise CorruptScan(f"{path}: a value is not a number") from None
    if not np.isfinite(pts[:, :2]).all():
        raise CorruptScan(f"{path}: x/y coordinates must be finite")
    fxy, base = parse_unit(xy_unit or "m")
    if base != "m":
        raise CorruptScan(f"xy_unit {xy_unit!r} is not a length unit")
    ix, x0, dx = _axis(path, pts[:, 0] * fxy, "x")
    iy, y0, dy = _axis(path, pts[:, 1] * fxy, "y")
    nx, ny = int(ix.max()) + 1, int(iy.max()) + 1
    check_shape(path, nx, ny)
    flat = iy * nx + ix
    if np.unique(flat).size != flat.size:
        raise CorruptScan(f"{path}: some grid points appear more than once")
    grid = np.full(nx * ny, np.nan)
    grid[flat] = pts[:, 2]
    chan = Channel("Height", key=0, unit=z_unit or "m")
    chan = select_channel(path, [chan], channel)
    return make_scan(path, FORMAT, grid.reshape(ny, nx), dx, dy, chan, [chan], rows_flipped=False,
                     extra={"x0": x0, "y0": y0, "points": int(len(pts))})
