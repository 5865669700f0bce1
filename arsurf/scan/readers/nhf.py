"""Nanosurf ``.nhf`` reader (HDF5 files of Nanosurf Studio; file versions 1.1 and 2.x).

Library: h5py (a core dependency) and our own reading of Nanosurf's attributes, following
Nanosurf's own reader (``nanosurf.utils.io.nhf_reader``, MIT, in the ``nanosurf-utils``
package, which needs the Nanosurf controller stack and Qt). NSFopen 2.2 reads ``.nhf`` too but
needs pandas, ignores the calibration offset and the element type (it scales every dataset as
int32 around 0), does not read the pixel size, and reshapes ``(Nx, Ny)``; so we own the parser.
On the vendor's example file our heights equal the vendor reader's and the vendor's own
Gwyddion export of the same measurement to 3e-21 m (tests).

Layout: root attributes ``nsf_file_version_major/minor``. Measurements are root groups named by
the attribute ``measurement_name`` (v2) or ``name`` (v1.1); their type is ``group_type`` (v2) or
``measurement_type`` (v1.1): ``image_line_based`` and ``wavemode_nma`` hold images,
``spectroscopy`` does not (a v2 group of type ``calibration`` holds the calibration graph). A
measurement's segments are subgroups named by ``segment_name`` / ``name`` (``Forward``,
``Backward``); a segment's channels are 1-D datasets named by ``signal_name`` / ``name``.

Image size: ``image_points_per_line`` x ``image_number_of_lines`` (v1.1) or ``rect_axis_size``
= (lines, points) (v2), or ``grid_number_of_columns/rows``; a channel is an image when it holds
exactly that many values (force-curve datasets of the same segment are skipped). Scan size in
metres: ``image_size_x/y`` or ``rect_axis_range`` = (y, x) or ``grid_width/height`` (the vendor's
order); pixel spacing = size / pixels.

Scaling (the vendor's): a raw value ``r`` of the dataset's element type with range
``[t_min, t_max]`` maps linearly onto the calibration range ``[s_min, s_max]``:
:math:`v = (r - t_{min})\\,(s_{max} - s_{min}) / (t_{max} - t_{min}) + s_{min}`, with
``base_calibration_min/max/unit`` (v1.1, integer type codes 0-7) or
``signal_calibration_min/max/unit`` (v2, type names; the dataset's HDF5 fill value marks missing
pixels, read as NaN). In v2 a channel whose ``signal_selected`` differs from its ``signal_id`` is
shown by Nanosurf in the selected signal: the calibration group's nodes (``signal_source_id`` ->
``signal_sink_id``, ``linear``/``exponential``/``logarithmic`` maps) are applied to the stored
values from the one to the other, as the vendor reader does. Units written as ``"Meter (m)"`` are read as ``m``.

Orientation: the vendor's reader flips the stored lines for display (``np.flipud``), so the
first stored line is the bottom of the image: rows are kept, row 0 = bottom.
"""
from __future__ import annotations

import contextlib
import math
import re
from pathlib import Path

import numpy as np

from arsurf.errors import CorruptScan
from arsurf.scan.readers._common import (Channel, check_shape, h5_text, make_scan, parse_unit, open_scan_hdf5,
                                         select_channel)

EXTENSIONS = (".nhf",)
FORMAT = "nhf"
#: v1.1 element type codes -> (numpy kind, type min, type max) (the vendor's table; no NaN value)
TYPES_V1 = {0: ("<i4", -(2.0**31), 2.0**31 - 1), 1: ("u1", 0.0, 2.0**8 - 1), 2: ("<u2", 0.0, 2.0**16 - 1),
            3: ("<u4", 0.0, 2.0**32 - 1), 4: ("<u8", 0.0, 2.0**64 - 1), 5: ("<i2", -(2.0**15), 2.0**15 - 1),
            6: ("<i8", -(2.0**63), 2.0**63 - 1), 7: ("<f8", 0.0, 1.0)}
#: v2 element type names -> (type min, type max); the extreme value is the NaN marker
TYPES_V2 = {"int32": (-(2.0**31) + 1, 2.0**31 - 1), "uint8": (0.0, 2.0**8 - 2), "uint16": (0.0, 2.0**16 - 2),
            "uint32": (0.0, 2.0**32 - 2), "uint64": (0.0, 2.0**64 - 2), "int16": (-(2.0**15) + 1, 2.0**15 - 1),
            "int64": (-(2.0**63) + 1, 2.0**63 - 1), "double": (0.0, 1.0)}
IMAGE_TYPES = ("image_line_based", "wavemode_nma")
_MAX_CHAIN = 16
_UNIT_IN_PARENS = re.compile(r"\(([^)]+)\)")


def sniff(head: bytes) -> bool:
    """False: the Nanosurf marker is a root attribute, not in the file's head
    (:func:`arsurf.scan.io.detect_format` opens HDF5 files to look, see :func:`is_nhf`)."""
    return False


def unit_of(text) -> str:
    """The unit in a Nanosurf unit text: ``"Meter (m)" -> "m"``, ``"V" -> "V"``."""
    s = h5_text(text).strip()
    m = _UNIT_IN_PARENS.search(s)
    return m.group(1).strip() if m else s


def is_nhf(f) -> bool:
    """Whether an open h5py File is a Nanosurf ``.nhf`` (root attribute ``nsf_file_version_major``)."""
    return "nsf_file_version_major" in f.attrs


def _num(path, attrs, key: str, what: str, index: int | None = None) -> float:
    if key not in attrs:
        raise CorruptScan(f"{path}: {what} has no attribute {key!r}")
    v = np.asarray(attrs[key]).reshape(-1)
    try:
        x = float(v[0 if index is None else index])
    except (TypeError, ValueError, IndexError):
        raise CorruptScan(f"{path}: {what} attribute {key!r} is not a number ({attrs[key]!r})") from None
    if not math.isfinite(x):
        raise CorruptScan(f"{path}: {what} attribute {key!r} is not finite ({x!r})")
    return x


def _version(path, f) -> tuple[int, int]:
    major = int(_num(path, f.attrs, "nsf_file_version_major", "the file"))
    minor = int(_num(path, f.attrs, "nsf_file_version_minor", "the file")) if "nsf_file_version_minor" in f.attrs \
        else 0
    if not ((major, minor) == (1, 1) or major == 2):
        raise CorruptScan(f"{path}: Nanosurf file version {major}.{minor} is not supported (1.1 and 2.x are, as by "
                          "Nanosurf's own reader)")
    return major, minor


def _size(path, attrs, what) -> tuple[int, int, float, float] | None:
    """(nx, ny, x range m, y range m) from a measurement's or segment's attributes, or None."""
    nx = ny = None
    if "image_points_per_line" in attrs and "image_number_of_lines" in attrs:
        nx, ny = (int(_num(path, attrs, k, what)) for k in ("image_points_per_line", "image_number_of_lines"))
    if "grid_number_of_columns" in attrs and "grid_number_of_rows" in attrs:
        nx, ny = (int(_num(path, attrs, k, what)) for k in ("grid_number_of_columns", "grid_number_of_rows"))
    if "rect_axis_size" in attrs:
        ny, nx = int(_num(path, attrs, "rect_axis_size", what, 0)), int(_num(path, attrs, "rect_axis_size", what, 1))
    if nx is None:
        return None
    xr = yr = None
    if "image_size_x" in attrs and "image_size_y" in attrs:
        xr, yr = _num(path, attrs, "image_size_x", what), _num(path, attrs, "image_size_y", what)
    if "rect_axis_range" in attrs:
        yr, xr = _num(path, attrs, "rect_axis_range", what, 0), _num(path, attrs, "rect_axis_range", what, 1)
    if "grid_width" in attrs and "grid_height" in attrs:
        xr, yr = _num(path, attrs, "grid_width", what), _num(path, attrs, "grid_height", what)
    if xr is None:
        raise CorruptScan(f"{path}: {what} gives {nx} x {ny} pixels but no scan size (image_size_x/y or "
                          "rect_axis_range)")
    return nx, ny, xr, yr


def _calibration_nodes(path, f) -> list[dict]:
    """The v2 calibration graph as directed edges (source -> sink, map, parameters)."""
    import h5py

    nodes = []
    for key in f.keys():
        g = f[key]
        if not (isinstance(g, h5py.Group) and h5_text(g.attrs.get("group_type", "")) == "calibration"):
            continue
        for d in g.values():
            a = d.attrs
            try:
                src, sink = h5_text(a["signal_source_id"]), h5_text(a["signal_sink_id"])
                kind, inv = h5_text(a["signal_mapping_type"]), h5_text(a["signal_invertibility"])
                par = [float(x) for x in np.asarray(a["signal_mapping_parameters"]).reshape(-1)]
                units = unit_of(a["signal_sink_unit"]), unit_of(a["signal_source_unit"])
            except (KeyError, TypeError, ValueError):
                continue  # the vendor reader also stops at an incomplete node
            if inv in ("right", "two_way"):
                nodes.append({"from": src, "to": sink, "map": kind, "par": par, "forward": inv == "right",
                              "unit": units[0]})
            if inv in ("left", "two_way"):
                nodes.append({"from": sink, "to": src, "map": kind, "par": par, "forward": True, "unit": units[1]})
        break
    return nodes


def _chain(path, nodes, start: str, target: str, what: str) -> list[dict]:
    """Depth-first path of calibration nodes from ``start`` to ``target`` (bounded depth)."""
    def walk(at, seen, depth):
        if depth > _MAX_CHAIN:
            return None
        for n in nodes:
            if n["from"] == at and n["to"] not in seen:
                if n["to"] == target:
                    return [n]
                rest = walk(n["to"], seen | {at}, depth + 1)
                if rest is not None:
                    return [n, *rest]
        return None

    found = walk(start, {start}, 0)
    if found is None:
        raise CorruptScan(f"{path}: {what}: no calibration leads from signal {start!r} to the selected {target!r}")
    return found


def _apply(path, node: dict, v: np.ndarray, what: str) -> np.ndarray:
    kind, par = node["map"], node["par"]
    need = 2 if kind.startswith("linear") else 3
    if len(par) < need or not all(math.isfinite(p) for p in par[:need]):
        raise CorruptScan(f"{path}: {what}: calibration map {kind!r} has parameters {par}")
    a, b = par[0], par[1]
    with np.errstate(all="ignore"):
        if kind in ("linear", "linear_non_invertible"):
            if not node["forward"]:
                if kind == "linear_non_invertible" or a == 0.0:
                    raise CorruptScan(f"{path}: {what}: calibration map {kind!r} ({par}) cannot be inverted")
                return (v - b) / a
            return v * a + b
        c = par[2]
        if kind in ("exponential", "logarithmic") and a != 0.0 and b != 0.0:
            if (kind == "exponential") == node["forward"]:
                return b * np.exp((v - c) / a)
            return a * np.log(v / b) + c
    raise CorruptScan(f"{path}: {what}: calibration map {kind!r} is not one Nanosurf defines")


def read(path: Path | str, channel: str | None = None):
    """Read one image channel of a ``.nhf`` file in SI units (default: the topography, forward).

    Channel names are ``"<signal> (<segment>)"``, e.g. ``"Topography (Forward)"``; with several
    image measurements in the file, ``"<measurement>: "`` comes first.
    """
    import h5py

    path = Path(path)
    size = path.stat().st_size
    try:
        with contextlib.ExitStack() as stack:
            f = stack.enter_context(open_scan_hdf5(path, "a Nanosurf .nhf file"))
            if not is_nhf(f):
                raise CorruptScan(f"{path}: no root attribute 'nsf_file_version_major'; not a Nanosurf .nhf file")
            major, minor = _version(path, f)
            mkey, tkey, skey, ckey = (("measurement_name", "group_type", "segment_name", "signal_name") if major >= 2
                                      else ("name", "measurement_type", "name", "name"))
            measurements = []
            for key in sorted(f.keys()):
                g = f[key]
                if isinstance(g, h5py.Group) and mkey in g.attrs:
                    kind = h5_text(g.attrs.get(tkey, ""))
                    if kind in IMAGE_TYPES:
                        measurements.append((key, h5_text(g.attrs[mkey]), kind))
            if not measurements:
                raise CorruptScan(f"{path}: no image measurement ({' or '.join(IMAGE_TYPES)}) in the file")
            chans: list[Channel] = []
            for key, mname, kind in measurements:
                g = f[key]
                geom = _size(path, g.attrs, f"measurement {mname!r}")
                for sk in sorted(g.keys()):
                    seg = g[sk]
                    if not (isinstance(seg, h5py.Group) and skey in seg.attrs):
                        continue
                    sname = h5_text(seg.attrs[skey])
                    sgeom = geom or _size(path, seg.attrs, f"segment {sname!r}")
                    if sgeom is None:
                        raise CorruptScan(f"{path}: measurement {mname!r} gives no image size")
                    nx, ny = sgeom[0], sgeom[1]
                    check_shape(path, nx, ny)
                    for dk in sorted(seg.keys(), key=lambda s: (len(s), s)):
                        ds = seg[dk]
                        if not (isinstance(ds, h5py.Dataset) and ckey in ds.attrs):
                            continue
                        if ds.ndim != 1 or ds.shape[0] != nx * ny:
                            continue  # force curves, per-pixel spectra: not an image of this grid
                        if ds.dtype.kind not in "iuf" or nx * ny * ds.dtype.itemsize > 64 * size + (1 << 20):
                            raise CorruptScan(f"{path}: {key}/{sk}/{dk} is {ds.dtype} x {ds.shape}, not a numeric "
                                              "image the file can hold")
                        a = ds.attrs
                        unit = unit_of(a.get("signal_calibration_unit" if major >= 2 else "base_calibration_unit",
                                             ""))
                        label = f"{h5_text(a[ckey])} ({sname})"
                        if len(measurements) > 1:
                            label = f"{mname}: {label}"
                        direction = {"forward": "forward", "backward": "backward"}.get(sname.strip().lower())
                        chans.append(Channel(label, key=(key, sk, dk), unit=unit, direction=direction,
                                             extra={"grid": sgeom, "measurement": mname, "type": kind}))
            if not chans:
                raise CorruptScan(f"{path}: the image measurements hold no channel of their image size")
            chan = select_channel(path, chans, channel)
            key, sk, dk = chan.key
            ds = f[key][sk][dk]
            a = dict(ds.attrs)
            raw = np.asarray(ds[()], dtype=np.float64)
            fill = ds.fillvalue
            nodes = _calibration_nodes(path, f) if major >= 2 else []
            meta = {k: h5_text(v) if isinstance(v, (bytes, np.bytes_, str)) else v
                    for k, v in f[key].attrs.items() if np.size(v) < 16}
    except OSError as exc:  # h5py's errors for a damaged file
        raise CorruptScan(f"{path}: the HDF5 structure is damaged ({str(exc).splitlines()[0]})") from None
    nx, ny, xr, yr = chan.extra["grid"]
    data, unit = _scale(path, raw, a, major, fill, nodes, chan.name)
    chan.unit = unit
    fz, base = parse_unit(unit)
    return make_scan(path, FORMAT, data.reshape(ny, nx), xr / nx, yr / ny, chan, chans, rows_flipped=False,
                     z_factor=fz, z_unit=base,
                     instrument={"software": "Nanosurf", "file_version": f"{major}.{minor}",
                                 "measurement": chan.extra["measurement"], "type": chan.extra["type"],
                                 **{k: meta[k] for k in sorted(meta)[:80]}})


def _scale(path, raw: np.ndarray, a: dict, major: int, fill, nodes, what: str) -> tuple[np.ndarray, str]:
    """Raw dataset values -> calibrated values and their unit (see the module docstring)."""
    etype = a.get("dataset_element_type")
    if major >= 2:
        name = h5_text(etype) if etype is not None else ""
        if name not in TYPES_V2:
            raise CorruptScan(f"{path}: {what}: dataset_element_type {name!r} is not a Nanosurf type "
                              f"({', '.join(TYPES_V2)})")
        tmin, tmax = TYPES_V2[name]
        lo_key, hi_key, unit_key = "signal_calibration_min", "signal_calibration_max", "signal_calibration_unit"
        missing = np.isnan(raw) if fill is None or (isinstance(fill, float) and math.isnan(fill)) else raw == fill
    else:
        try:
            tmin, tmax = TYPES_V1[int(np.asarray(etype).reshape(-1)[0])][1:]
        except (KeyError, TypeError, ValueError, IndexError):
            raise CorruptScan(f"{path}: {what}: dataset_element_type {etype!r} is not a Nanosurf type code "
                              "(0-7)") from None
        lo_key, hi_key, unit_key = "base_calibration_min", "base_calibration_max", "base_calibration_unit"
        missing = None
    if unit_key not in a and lo_key not in a:
        return raw, ""  # an uncalibrated channel (the vendor leaves it raw too)
    smin = _num(path, a, lo_key, what) if lo_key in a else 0.0
    smax = _num(path, a, hi_key, what) if hi_key in a else 1.0
    unit = unit_of(a.get(unit_key, ""))
    if smax == smin:
        raise CorruptScan(f"{path}: {what}: the calibration range {lo_key}..{hi_key} is empty ({smin!r}): every "
                          "value would be equal")
    v = (raw - tmin) * ((smax - smin) / (tmax - tmin)) + smin
    if major >= 2 and "signal_selected" in a and "signal_id" in a:
        target, source = h5_text(a["signal_selected"]), h5_text(a["signal_id"])
        if target and target != source:  # the graph maps the stored values of signal_id to the selected signal
            v = raw
            for node in _chain(path, nodes, source, target, what):
                v = _apply(path, node, v, what)
                unit = node["unit"]
    if missing is not None and missing.any():
        v = np.where(missing, np.nan, v)
    return v, unit
