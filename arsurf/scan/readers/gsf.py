"""Gwyddion Simple Field (``.gsf``) reader and writer.

Library: our own parser (about 60 lines), cross-checked against ``gsffile`` in the tests.
Why not ``gsffile.read_gsf``: it splits each header line with ``line.split("=")`` and so rejects
valid files whose values contain ``=`` (the Gwyddion spec splits at the first ``=``), it
decodes the header as strict UTF-8, and it raises on trailing bytes. The format is small
enough that owning it costs less than working around that, and saving a scan should not need
an optional package.

Format (gwyddion.net, "Gwyddion Simple Field"): the line ``Gwyddion Simple Field 1.0``, then
``Key = Value`` lines (``XRes``, ``YRes`` required; ``XReal``, ``YReal`` in ``XYUnits``,
``ZUnits``, ``Title``, offsets optional), then 1-4 NUL bytes padding the header to a multiple
of 4, then ``XRes*YRes`` little-endian float32 values, row by row.

What the format lets us check (as Gwyddion's ``gsf.c`` does): the data fill the file exactly
(``4 XRes YRes`` bytes after the padding; a ``YRes`` that disagrees with the data is refused,
Gwyddion's strict size check), the padding is NUL bytes. Units: the values are in ``ZUnits``; a
file without ``ZUnits`` states no unit (the spec gives no default), so its channel is unitless
and not a height unless ``z_unit`` is passed to :func:`arsurf.load_scan`; a ``ZUnits`` of ``V``
gives a channel in volts, flagged ``metadata["height"] = False``, never metres. A file without
``XReal``/``YReal`` does not state its size (the spec's default, 1 ``XYUnits``, is no AFM field)
and is refused with :class:`~arsurf.errors.MissingCalibration`.

Orientation: Gwyddion shows row 0 at the top (its y axis points down the screen), so the rows
are flipped on reading (row 0 = bottom, y up) and flipped back on writing.
Pixel spacing: ``dx = XReal / XRes`` (Gwyddion's convention: XReal is the field width, N pixels).
Precision: data are float32 by the spec, so a save/load round trip is exact to float32
(relative 2**-24 ~ 6e-8); the spacings are written with ``repr`` and round-trip exactly.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from arsurf._files import atomic_write
from arsurf.errors import CorruptScan, MissingCalibration, ScanError
from arsurf.scan.readers._common import (
    Channel,
    check_data_size,
    check_shape,
    flip_rows,
    frombuffer,
    make_scan,
    parse_float,
    parse_int,
    parse_unit,
    select_channel,
)

MAGIC = b"Gwyddion Simple Field 1.0"
EXTENSIONS = (".gsf",)
FORMAT = "gsf"


def sniff(head: bytes) -> bool:
    """True when the file starts with the GSF magic line."""
    return head.startswith(MAGIC + b"\n") or head.startswith(MAGIC + b"\r\n")


def parse_header(path, buf: bytes) -> tuple[dict[str, str], int]:
    """The ``Key = Value`` header as a dict and the offset of the data."""
    if not sniff(buf[:64]):
        raise CorruptScan(f"{path}: missing the 'Gwyddion Simple Field 1.0' magic line")
    end = buf.find(b"\x00")
    if end < 0:
        raise CorruptScan(f"{path}: the GSF header is not terminated by a NUL byte (truncated file)")
    text = buf[:end].decode("utf-8", errors="replace")
    header: dict[str, str] = {}
    for line in text.splitlines()[1:]:
        if not line.strip():
            continue
        if "=" not in line:
            raise CorruptScan(f"{path}: GSF header line {line[:60]!r} is not 'Key = Value'")
        key, value = line.split("=", 1)
        header[key.strip()] = value.strip()
    data_start = end + (4 - end % 4)
    if buf[end:data_start].strip(b"\x00"):
        raise CorruptScan(f"{path}: the GSF header padding (bytes {end}..{data_start}) is not NUL bytes (corrupt header)")
    return header, data_start


def read(path: Path | str, channel: str | None = None, *, z_unit: str | None = None):
    """Read a ``.gsf`` file as a :class:`~arsurf.scan.scan.Scan` (single channel, rows flipped).

    ``z_unit`` is the unit of the values of a file whose header has no ``ZUnits``; a file that
    states one keeps it (passing another is refused).

    Examples
    --------
    >>> scan = read("wedge_Z_raw.gsf")  # doctest: +SKIP
    """
    buf = Path(path).read_bytes()
    header, start = parse_header(path, buf)
    for key in ("XRes", "YRes"):
        if key not in header:
            raise CorruptScan(f"{path}: the GSF header has no {key}")
    nx = parse_int(path, header["XRes"], "XRes")
    ny = parse_int(path, header["YRes"], "YRes")
    check_shape(path, nx, ny)
    check_data_size(path, len(buf) - start, 4 * nx * ny, f"XRes x YRes = {nx} x {ny} float32 pixels", exact=True)
    xy_factor, xy_base = parse_unit(header.get("XYUnits", "m"))
    if xy_base != "m":
        raise CorruptScan(f"{path}: XYUnits {header.get('XYUnits')!r} is not a length unit")
    missing = [k for k in ("XReal", "YReal") if k not in header]
    if missing:
        raise MissingCalibration(f"{path}: the GSF header has no {'/'.join(missing)} (the physical size of the "
                                 "image); the spec's default of 1 m is no AFM scan: add it to the header")
    xreal = parse_float(path, header["XReal"], "XReal") * xy_factor
    yreal = parse_float(path, header["YReal"], "YReal") * xy_factor
    if "ZUnits" in header and z_unit is not None and parse_unit(z_unit) != parse_unit(header["ZUnits"]):
        raise CorruptScan(f"{path}: the file states ZUnits = {header['ZUnits']}; z_unit={z_unit!r} applies only "
                          "to files without ZUnits: remove it")
    data = frombuffer(path, buf, start, "<f4", nx * ny, "the GSF data").reshape(ny, nx)
    dx, dy = xreal / nx, yreal / ny
    # our writer adds the exact spacings (XReal/XRes can differ from dx in the last bit)
    for key, nominal in (("Arsurf_dx", dx), ("Arsurf_dy", dy)):
        if key in header:
            exact = parse_float(path, header[key], key)
            if np.isfinite(exact) and abs(exact - nominal) <= 1e-9 * abs(nominal):
                dx, dy = (exact, dy) if key == "Arsurf_dx" else (dx, exact)
    title = header.get("Title", "") or "Height"
    chan = Channel(title, key=0, unit=header.get("ZUnits", z_unit if z_unit is not None else ""))
    chan = select_channel(path, [chan], channel)
    meta = {k: v for k, v in header.items() if k not in ("XRes", "YRes")}
    return make_scan(
        path, FORMAT, flip_rows(data), dx, dy, chan, [chan], rows_flipped=True,
        instrument={k: v for k, v in meta.items() if k.lower().startswith("neaspec")},
        extra={"header": meta},
    )


def write(scan, path: Path | str) -> None:
    """Write ``scan`` as GSF: float32 metres, rows flipped back to Gwyddion's top-first order.

    The header holds ``XRes``, ``YRes``, ``XReal = nx*dx``, ``YReal = ny*dy``, ``XYUnits = m``,
    ``ZUnits`` (metadata ``z_unit``, default ``m``), ``Title`` (the channel) and the extra keys
    ``Arsurf_dx``/``Arsurf_dy`` (repr of the spacings, so they round-trip bit-exactly; other
    GSF readers ignore unknown keys).
    NaN pixels are written as NaN (the spec allows it).
    """
    ny, nx = scan.shape
    title = str(scan.channel).replace("\n", " ").replace("\x00", "")
    z_unit = str(scan.metadata.get("z_unit") or "m").replace("\n", " ")
    lines = [
        MAGIC.decode(),
        f"XRes = {nx}",
        f"YRes = {ny}",
        f"XReal = {nx * scan.dx!r}",
        f"YReal = {ny * scan.dy!r}",
        "XYUnits = m",
        f"ZUnits = {z_unit}",
        f"Title = {title}",
        f"Arsurf_dx = {scan.dx!r}",
        f"Arsurf_dy = {scan.dy!r}",
    ]
    head = ("\n".join(lines) + "\n").encode("utf-8")
    pad = b"\x00" * (4 - len(head) % 4)
    data = np.ascontiguousarray(scan.heights[::-1, :], dtype="<f4")
    with atomic_write(path, what="scan file", error=ScanError) as fh:
        fh.write(head + pad + data.tobytes())
