"""JPK HDF5 image reader (``.h5-jpk``, JPK/Bruker SPM software 8.x; "JPK SCAN" format 3.0).

Library: h5py (a core dependency) and our own reading of the JPK attributes. AFMReader's
``h5_jpk.load_h5jpk`` reads the same files; we follow its layout (checked on the real file in
the tests) but walk the calibration chain ourselves and validate every field first.

Format (pycroscopy/USID layout written by JPK): root attribute ``file-format-info = "JPK SCAN"``;
``Measurement_000/Channel_NNN/<Name>`` int32 datasets of shape (ilength x jlength, frames): one
column per frame (a movie of ``frames`` images), pixels in scan order, x (the fast axis,
``Position_Indices`` column 0) fastest. The grid is in the measurement's attributes
``position-pattern.grid.{ilength, jlength, ulength, vlength}`` (pixels and metres along x, y).

Calibration: a channel's attributes describe ``encoder.scaling`` (raw integer -> the base slot,
``conversions.base``) and calibration slots ``conversion.<slot>.scaling.{multiplier, offset,
unit.unit}``, each applied to the value of its ``base-calibration-slot``; the default slot
(``conversions.default``) is reached by walking that chain from the base:

.. math:: v_0 = m_e\\,\\text{raw} + o_e,\\qquad v_{k+1} = m_k v_k + o_k

``net-encoder.scaling`` is JPK's own composition of that chain; we check that both agree (as
they do on the real file) and refuse a file where they do not.

Orientation: the first stored line is the smallest y (``Position_Values``), so rows are kept as
stored: row 0 = bottom (AFMReader flips them for display). Pixel spacing: ``ulength / ilength``
and ``vlength / jlength`` (as AFMReader).

Channel names: ``"<Name> (trace|retrace)"`` from the dataset name and the ``retrace`` attribute;
frames after the first are ``"<Name> (retrace) frame <k>"`` (k from 1).
"""
from __future__ import annotations

import contextlib
import math
from pathlib import Path

import numpy as np

from arsurf.errors import ChannelNotFound, CorruptScan
from arsurf.scan.readers._common import (
    Channel,
    h5_text,
    check_shape,
    make_scan,
    parse_unit,
    open_scan_hdf5,
    select_channel,
)

EXTENSIONS = (".h5-jpk",)
FORMAT = "h5-jpk"
_MAX_CHAIN = 16
_MAX_FRAMES = 100000


def sniff(head: bytes) -> bool:
    """False: the JPK marker is a root attribute stored at the end of the file, not in its head
    (:func:`arsurf.scan.io.detect_format` opens HDF5 files to look, see ``is_h5jpk``)."""
    return False


def _number(path, attrs, key: str, what: str) -> float:
    if key not in attrs:
        raise CorruptScan(f"{path}: {what} has no attribute {key!r}")
    v = attrs[key]
    try:
        x = float(np.asarray(v).reshape(-1)[0]) if not isinstance(v, (bytes, np.bytes_)) else float(h5_text(v))
    except (TypeError, ValueError, IndexError):
        raise CorruptScan(f"{path}: {what} attribute {key!r} is not a number ({v!r})") from None
    if not math.isfinite(x):
        raise CorruptScan(f"{path}: {what} attribute {key!r} is not finite ({x!r})")
    return x


def is_h5jpk(f) -> bool:
    """Whether an open h5py File is a JPK scan (root attribute ``file-format-info``)."""
    return h5_text(f.attrs.get("file-format-info", b"")).strip().upper() == "JPK SCAN"


def calibration(path, attrs, what: str) -> tuple[float, float, str]:
    """(multiplier, offset, unit) from a raw integer to the channel's default calibration slot."""
    m = _number(path, attrs, "encoder.scaling.multiplier", what)
    o = _number(path, attrs, "encoder.scaling.offset", what)
    unit = h5_text(attrs.get("encoder.scaling.unit.unit", b""))
    base = h5_text(attrs.get("conversions.base", b"")).strip()
    slot = h5_text(attrs.get("conversions.default", base.encode())).strip() or base
    chain = []
    while slot and slot != base:
        if len(chain) > _MAX_CHAIN or slot in chain:
            raise CorruptScan(f"{path}: {what}: the calibration slots loop or nest too deep ({chain + [slot]})")
        chain.append(slot)
        key = f"conversion.{slot}.base-calibration-slot"
        if key not in attrs:
            raise CorruptScan(f"{path}: {what}: calibration slot {slot!r} has no {key!r}")
        slot = h5_text(attrs[key]).strip()
    for s in reversed(chain):
        style = h5_text(attrs.get(f"conversion.{s}.scaling.style", b"offsetmultiplier"))
        if style != "offsetmultiplier":
            raise CorruptScan(f"{path}: {what}: calibration slot {s!r} has scaling style {style!r}; only "
                              "'offsetmultiplier' is defined")
        ms = _number(path, attrs, f"conversion.{s}.scaling.multiplier", what)
        os_ = _number(path, attrs, f"conversion.{s}.scaling.offset", what)
        m, o = m * ms, o * ms + os_
        unit = h5_text(attrs.get(f"conversion.{s}.scaling.unit.unit", unit.encode()))
    if "net-encoder.scaling.multiplier" in attrs and "net-encoder.scaling.offset" in attrs:
        nm = _number(path, attrs, "net-encoder.scaling.multiplier", what)
        no = _number(path, attrs, "net-encoder.scaling.offset", what)
        scale = max(abs(o), abs(no), abs(m) * 2**31, 1e-300)
        if not (math.isclose(nm, m, rel_tol=1e-9, abs_tol=0) and abs(no - o) <= 1e-9 * scale):
            raise CorruptScan(f"{path}: {what}: the calibration chain gives {m:g} x raw + {o:g} but the file's "
                              f"net encoder says {nm:g} x raw + {no:g}; the calibration attributes are damaged")
    if m == 0.0:
        raise CorruptScan(f"{path}: {what}: the calibration multiplier is 0 (every pixel would be equal)")
    return m, o, unit


def read(path: Path | str, channel: str | None = None, frame: int | None = None):
    """Read one channel and frame of a ``.h5-jpk`` file in SI units (default: the height,
    trace if recorded, first frame); ``frame`` (from 0) selects the frame of the channel named
    without its ``frame <k>`` suffix."""
    import h5py

    path = Path(path)
    size = path.stat().st_size
    try:
        with contextlib.ExitStack() as stack:
            f = stack.enter_context(open_scan_hdf5(path, "a JPK .h5-jpk file"))
            if not is_h5jpk(f):
                raise CorruptScan(f"{path}: the root attribute 'file-format-info' is not 'JPK SCAN' "
                                  f"(got {h5_text(f.attrs.get('file-format-info', b''))!r}); not a JPK scan file")
            meas = sorted(k for k in f.keys() if k.startswith("Measurement_"))
            if not meas or not isinstance(f[meas[0]], h5py.Group):
                raise CorruptScan(f"{path}: no 'Measurement_000' group (keys: {sorted(f.keys())[:10]})")
            mg = f[meas[0]]
            ni = int(_number(path, mg.attrs, "position-pattern.grid.ilength", "the grid"))
            nj = int(_number(path, mg.attrs, "position-pattern.grid.jlength", "the grid"))
            check_shape(path, ni, nj)
            ul = _number(path, mg.attrs, "position-pattern.grid.ulength", "the grid")
            vl = _number(path, mg.attrs, "position-pattern.grid.vlength", "the grid")
            unit = h5_text(mg.attrs.get("position-pattern.grid.unit.unit", b"m"))
            f_xy, base_xy = parse_unit(unit)
            if base_xy != "m":
                raise CorruptScan(f"{path}: the grid unit {unit!r} is not a length")
            chans: list[Channel] = []
            frames_of: dict[str, int] = {}
            for ck in sorted(mg.keys()):
                g = mg[ck]
                if not (ck.startswith("Channel_") and isinstance(g, h5py.Group)):
                    continue
                data = [k for k in g.keys() if k != "thumbnail" and isinstance(g[k], h5py.Dataset)]
                if len(data) != 1:
                    continue
                ds = g[data[0]]
                if ds.ndim != 2 or ds.dtype.kind not in "iuf" or ds.shape[0] != ni * nj:
                    raise CorruptScan(f"{path}: {ck}/{data[0]} is {ds.dtype} of shape {ds.shape}; a "
                                      f"({ni}x{nj}, frames) numeric array is expected from the grid")
                nf = int(ds.shape[1])
                if not 1 <= nf <= _MAX_FRAMES:
                    raise CorruptScan(f"{path}: {ck}/{data[0]} holds {nf} frames")
                if ni * nj * nf * ds.dtype.itemsize > 256 * size + (1 << 20):
                    raise CorruptScan(f"{path}: {ck}/{data[0]} claims {ni}x{nj}x{nf} values, more than a "
                                      f"{size}-byte file can hold")
                retrace = h5_text(g.attrs.get("retrace", b"false")).strip().lower() == "true"
                label = f"{data[0]} ({'retrace' if retrace else 'trace'})"
                frames_of[ck] = nf
                for k in range(nf):
                    chans.append(Channel(label if k == 0 else f"{label} frame {k}", key=(ck, data[0], k),
                                         direction="backward" if retrace else "forward",
                                         extra={"frame": k, "frames": nf}))
            if not chans:
                raise CorruptScan(f"{path}: {meas[0]} holds no image channel")
            units = {}
            for c in chans:  # units for the listing (a damaged calibration is reported when that channel is read)
                ck = c.key[0]
                if ck not in units:
                    try:
                        units[ck] = calibration(path, mg[ck].attrs, ck)[2]
                    except CorruptScan:
                        units[ck] = ""
                c.unit = units[ck]
            order = sorted(range(len(chans)), key=lambda i: chans[i].extra["frame"])  # frame 0 first
            chans = [chans[i] for i in order]
            if frame is None:
                chan = select_channel(path, chans, channel)
            else:
                first = select_channel(path, [c for c in chans if c.extra["frame"] == 0], channel)
                nf = first.extra["frames"]
                if isinstance(frame, bool) or not isinstance(frame, (int, np.integer)) or not 0 <= frame < nf:
                    raise ChannelNotFound(f"frame {frame!r} is not in {path}: {first.name!r} has frames 0..{nf - 1}")
                chan = next(c for c in chans if c.key == (first.key[0], first.key[1], int(frame)))
            ck, dname, frame = chan.key
            m, o, zunit = calibration(path, mg[ck].attrs, ck)
            chan.unit = zunit
            raw = np.asarray(mg[ck][dname][:, frame], dtype=np.float64)
            if raw.shape != (ni * nj,):
                raise CorruptScan(f"{path}: {ck}/{dname} frame {frame} has {raw.shape} values, not {ni * nj}")
            start = mg["meta-data/start-times"][()] if "meta-data/start-times" in mg else None
    except OSError as exc:  # h5py's errors for a damaged file
        raise CorruptScan(f"{path}: the HDF5 structure is damaged ({str(exc).splitlines()[0]})") from None
    data = (raw * m + o).reshape(nj, ni)
    f_z, base_z = parse_unit(zunit)
    t0 = None
    if start is not None and np.size(start) > frame:
        t0 = float(np.asarray(start).reshape(-1)[frame]) / 1e3  # ms since the epoch -> s
    return make_scan(path, FORMAT, data, ul * f_xy / ni, vl * f_xy / nj, chan, chans, rows_flipped=False,
                     z_factor=f_z, z_unit=base_z,
                     instrument={"software": "JPK SPM", "format": "JPK SCAN"},
                     extra={"frame": frame, "frames": frames_of.get(ck, 1), "frame_start_time_s": t0,
                            "calibration": {"multiplier": m, "offset": o, "unit": zunit}})
