"""Load and save AFM/STM scan files: :func:`load_scan` and :func:`save_scan`.

:func:`load_scan` detects the format from the file's content (magic bytes, header, TIFF tags,
Igor checksum) and falls back to the extension only when the content says nothing, so a
renamed file is still read right. Every reader returns a :class:`~arsurf.scan.scan.Scan` in
the project convention: ``heights[iy, ix]`` float64 metres, ``dx``/``dy`` in metres, x grows
with the column, y with the row, **row 0 is the bottom of the image** (y up, z out of the
sample: a right-handed frame). Formats that store the top row first are flipped;
``metadata["rows_flipped"]`` says whether this file was.

Supported formats (module in :mod:`arsurf.scan.readers`, library used):

=================  ===============================  ===========================================
format             extensions                       reader
=================  ===============================  ===========================================
``gwy``            .gwy                             own parser (gwyfile is unsafe on damaged files)
``gsf``            .gsf                             own parser and writer (checked against gsffile)
``sxm``            .sxm                             own parser (nanonispy broken, pySPM hangs)
``ibw``            .ibw                             igor2 after our header check; own labels
``nanoscope``      .spm, .000-.999                  own parser (pySPM hangs on damaged files)
``jpk``            .jpk                             tifffile + own JPK calibration slots
``park-tiff``      .tiff, .tif                      tifffile + own Park header
``nid``            .nid                             own parser
``wsxm``           .top, .stp, .tom                 own parser
``ascii-matrix``   .txt, .asc, .dat, .csv           own (numpy)
``xyz``            .xyz                             own (numpy)
``mdt``            .mdt                             own parser (NT-MDT scanned and MDA frames)
``asd``            .asd                             own parser (HS-AFM movie; ``frame=`` selects)
``h5-jpk``         .h5-jpk                          h5py + own JPK calibration chain
``nhf``            .nhf                             h5py + own Nanosurf calibration (vendor's rules)
``topostats``      .topostats                       h5py
``npy``/``npz``    .npy, .npz                       numpy (no pickle)
=================  ===============================  ===========================================

Default channel: the first height/topography channel recorded forward (trace), else the first
without a direction, else the first recorded backward (retrace); ``metadata["channels"]``
lists them all, ``metadata["direction"]`` says which was read. NaN pixels are kept (counted
in ``metadata["nan_count"]``; infinite values become NaN): fill them with
:func:`arsurf.inpaint` before fitting.

What a header says is checked against what the file holds and what an AFM can be before it
becomes a Scan (the plausibility rules of :mod:`arsurf.scan.readers._common`: data sizes,
finite non-zero z scales, pixel spacings, heights, units); ``metadata["height"]`` says whether
the channel is topography, and :func:`arsurf.fit_surface` refuses one that is not.

Errors are :class:`arsurf.errors.ScanError` subclasses naming the file and the problem:
:class:`~arsurf.errors.ScanFileNotFound`, :class:`~arsurf.errors.UnknownFormat`,
:class:`~arsurf.errors.CorruptScan` (truncated or inconsistent; any exception of a
third-party parser is wrapped in it), :class:`~arsurf.errors.UnsupportedScan` (a valid file of a
kind arsurf does not read: Gwyddion 1.x, force curves, an RGB TIFF, a Nanonis grid; the message says
what it is), :class:`~arsurf.errors.ChannelNotFound` (lists the
channels), :class:`~arsurf.errors.InvalidHeights` (e.g. no finite pixel) and
:class:`MissingCalibration` (a bare matrix without spacing or unit).
"""
from __future__ import annotations

import importlib
import inspect
import os
from pathlib import Path

import numpy as np

from arsurf.errors import (
    ArsurfError,
    CorruptScan,
    InvalidHeights,
    MissingDependency,
    ScanError,
    ScanFileNotFound,
    UnknownFormat,
    UnsupportedScan,
)
from arsurf.errors import MissingCalibration
from arsurf.scan.readers._common import HDF5_SIGNATURE

__all__ = ["load_scan", "save_scan", "detect_format", "format_extensions", "unsupported_kind", "FORMATS",
           "MissingCalibration"]

#: format name -> reader module, in sniffing order (strong binary magics first, text last)
FORMATS: dict[str, str] = {
    "npy": "arsurf.scan.readers.npy",
    "npz": "arsurf.scan.readers.npz",
    "gwy": "arsurf.scan.readers.gwy",
    "gsf": "arsurf.scan.readers.gsf",
    "sxm": "arsurf.scan.readers.sxm",
    "nanoscope": "arsurf.scan.readers.nanoscope",
    "nid": "arsurf.scan.readers.nid",
    "mdt": "arsurf.scan.readers.mdt",
    "wsxm": "arsurf.scan.readers.wsxm",
    "jpk": "arsurf.scan.readers.jpk",
    "park-tiff": "arsurf.scan.readers.park",
    "ibw": "arsurf.scan.readers.ibw",
    "asd": "arsurf.scan.readers.asd",
    "h5-jpk": "arsurf.scan.readers.h5jpk",
    "nhf": "arsurf.scan.readers.nhf",
    "topostats": "arsurf.scan.readers.topostats",
    "xyz": "arsurf.scan.readers.xyz",
    "ascii-matrix": "arsurf.scan.readers.ascii_matrix",
}
_TEXT_FORMATS = ("xyz", "ascii-matrix")
_WRITERS = {".gsf": "gsf", ".gwy": "gwy", ".npz": "npz", ".npy": "npy"}
HEAD_BYTES = 1 << 16


def _module(fmt: str):
    return importlib.import_module(FORMATS[fmt])


def _ext_map() -> dict[str, str]:
    out: dict[str, str] = {}
    for fmt in FORMATS:
        for ext in _module(fmt).EXTENSIONS:
            out.setdefault(ext, fmt)
    return out


def format_extensions() -> dict[str, str]:
    """Each format's extensions as one short text (NanoScope's numbered ones as ``.000-.999``).

    >>> format_extensions()["nanoscope"]
    '.spm, .000-.999'
    """
    out = {}
    for fmt in FORMATS:
        exts = _module(fmt).EXTENSIONS
        named = [e for e in exts if not e[1:].isdigit()]
        numbered = " .000-.999" if len(named) < len(exts) else ""
        out[fmt] = ", ".join(named) + ("," if named and numbered else "") + numbered
    return {k: v.strip() for k, v in out.items()}


def detect_format(path: str | os.PathLike, head: bytes | None = None) -> str:
    """The format name of ``path``: by content first, by extension when the content is silent.

    Raises
    ------
    ScanFileNotFound, UnknownFormat
    """
    path = Path(path)
    if head is None:
        head = _head(path)
    for fmt in FORMATS:
        if fmt in _TEXT_FORMATS:
            continue
        if _module(fmt).sniff(head):
            return fmt
    ext = path.suffix.lower()
    ext_fmt = _ext_map().get(ext)
    if head.startswith(HDF5_SIGNATURE):  # HDF5 formats mark themselves in attributes/datasets, not in the head bytes
        h5_fmt = _sniff_hdf5(path)
        if h5_fmt is not None:
            return h5_fmt
    text_fmt = next((f for f in _TEXT_FORMATS if _module(f).sniff(head)), None)
    if text_fmt is not None:
        # a numeric table: the extension decides between XYZ and matrix when it names one
        return ext_fmt if ext_fmt in _TEXT_FORMATS else text_fmt
    kind = unsupported_kind(head)
    if kind is not None:
        raise UnsupportedScan(f"{path}: {kind}")
    if ext_fmt in _TEXT_FORMATS and _is_binary(head):
        raise UnknownFormat(f"{path}: a binary file, not a text table as its extension {ext!r} suggests (binary "
                            f"layouts such as SPIEPy's raw .dat say nothing of their shape or units); export it as a "
                            f"text matrix, .gsf or .npy (arsurf formats lists what arsurf reads)")
    if ext_fmt in ("npz", "npy") and not head.startswith(b"PK"):  # numpy would take them for a pickle
        raise CorruptScan(f"{path}: not a NumPy {ext} file (its first bytes are {head[:8]!r}, not the "
                          f"{'zip archive' if ext_fmt == 'npz' else 'NPY'} signature); is it another format renamed?")
    if ext_fmt is not None:  # the content is silent: trust the extension (the reader says what is wrong)
        return ext_fmt
    raise UnknownFormat(
        f"{path}: neither the content nor the extension {ext or '(none)'!r} identify a supported scan "
        f"format; supported: {', '.join(FORMATS)} (`arsurf formats` lists their extensions)"
    )


def _is_binary(head: bytes) -> bool:
    """True when ``head`` is not text: a NUL byte, or not UTF-8/Latin-1 printable in the main."""
    if b"\x00" in head:
        return True
    sample = head[:4096]
    controls = sum(1 for b in sample if b < 32 and b not in (9, 10, 13))
    return bool(sample) and controls > 0.01 * len(sample)


#: valid files of kinds arsurf does not read, by their first bytes: (test, what the file is)
_UNSUPPORTED = (
    (lambda h: h.startswith(b"GWYO"), "a Gwyddion 1.x file (GWYO magic), an older format that arsurf does not read; "
     "open it in Gwyddion 2 and save it again (as .gwy or .gsf)"),
    (lambda h: h.startswith(b'Grid dim="'), "a Nanonis grid spectroscopy file (.3ds): spectra on a grid, not a height "
     "image; give the .sxm scan recorded with it"),
    (lambda h: h.startswith(b"Experiment\t"), "a Nanonis spectroscopy file (.dat: bias or Z spectroscopy curves), "
     "not a height image; give the .sxm scan"),
    (lambda h: h.startswith(b"PK\x03\x04") and (b"header.properties" in h[:512] or b"segments/" in h[:512]),
     "a JPK force-curve archive (.jpk-force / .jpk-qi-data): force curves, not a height image; give the .jpk scan"),
)


def unsupported_kind(head: bytes) -> str | None:
    """What a valid file that arsurf does not read is (a sentence with the way out), or None.

    TIFFs: a TIFF without the Park or JPK tags (sniffed before this) is a picture, not a
    calibrated height map: an RGB one is named as such.

    >>> unsupported_kind(b"GWYO" + b"GwyContainer")[:22]
    'a Gwyddion 1.x file (G'
    """
    for test, what in _UNSUPPORTED:
        if test(head):
            return what
    from arsurf.scan.readers._common import tiff_first_ifd_tags

    tags = tiff_first_ifd_tags(head)
    if tags:
        bo = "<" if head[:2] == b"II" else ">"

        def short(code, default):
            if code not in tags:
                return default
            typ, _, value = tags[code]
            return int.from_bytes(value[:2], "little" if bo == "<" else "big") if typ == 3 else \
                int.from_bytes(value[:4], "little" if bo == "<" else "big")

        samples, photometric = short(277, 1), short(262, 1)
        if samples >= 3 or photometric == 2:
            return (f"an RGB TIFF picture ({samples} samples per pixel): colours, not heights; export the height "
                    "channel from the instrument's software (.gsf, text matrix) or give the scan file")
        return ("a TIFF without the Park Systems or JPK tags: an image with no height calibration; export the height "
                "channel as .gsf or a text matrix, or give the instrument's scan file")
    return None




def _sniff_hdf5(path: Path) -> str | None:
    """``"h5-jpk"``, ``"nhf"`` or ``"topostats"`` when an HDF5 file says so in its content, else
    None (a damaged file: None, and the extension decides; its reader then names the damage).
    A file :func:`arsurf._h5safe.open_hdf5` refuses (a feature reaching outside it) is refused here,
    once, with its message."""
    from arsurf._h5safe import open_hdf5
    from arsurf.scan.readers.h5jpk import is_h5jpk
    from arsurf.scan.readers.nhf import is_nhf

    try:
        f = open_hdf5(path, "scan file", error=CorruptScan, name=str(path))
    except CorruptScan:
        raise
    except Exception:  # noqa: BLE001 - h5py cannot parse it: the content does not say
        return None
    try:
        with f:
            if is_h5jpk(f):
                return "h5-jpk"
            if is_nhf(f):
                return "nhf"
            if "image" in f and "pixel_to_nm_scaling" in f:
                return "topostats"
    except Exception:  # noqa: BLE001 - any failure or refusal: "the content does not say" (the reader names it)
        return None
    return None


def _head(path: Path) -> bytes:
    if not path.exists():
        raise ScanFileNotFound(f"scan file {str(path)!r} does not exist; check the path")
    if not path.is_file():
        raise ScanFileNotFound(f"{str(path)!r} is not a file (a directory?); give the path of a scan file")
    try:
        with open(path, "rb") as fh:
            return fh.read(HEAD_BYTES)
    except OSError as exc:
        raise ScanFileNotFound(f"scan file {str(path)!r} cannot be opened: {exc}") from exc


def load_scan(
    path: str | os.PathLike,
    channel: str | None = None,
    *,
    dx: float | None = None,
    dy: float | None = None,
    xy_unit: str | None = None,
    z_unit: str | None = None,
    frame: int | None = None,
):
    """Read one channel of a scan file as a :class:`~arsurf.scan.scan.Scan` in SI units.

    Parameters
    ----------
    path : str or path-like
        The scan file; its format is detected from its content (see the module docstring).
    channel : str, optional
        Channel name as listed in ``metadata["channels"]`` (case-insensitive; the name without
        its ``" (direction)"`` suffix works when unique). Default: the topography channel,
        forward/trace if recorded, else retrace.
    dx, dy : float, optional, metres
        Pixel spacing, only for files that do not state it (bare ASCII matrix, ``.npy``).
    xy_unit, z_unit : str, optional
        Units of the coordinates/values, only for files that do not state them (``"nm"``...).
    frame : int, optional
        Frame of a movie (high-speed AFM ``.asd``, JPK ``.h5-jpk``), counted from 0 (default
        0); ``metadata["frames"]`` says how many there are.

    Returns
    -------
    Scan
        ``heights`` (ny, nx) float64 in metres (other channels in their SI unit, see
        ``metadata["z_unit"]``), NaN for missing pixels; ``metadata`` has ``format``,
        ``channels``, ``direction``, ``nan_count``, ``rows_flipped`` and ``instrument``.

    Raises
    ------
    ScanFileNotFound, UnknownFormat, CorruptScan, UnsupportedScan, ChannelNotFound, InvalidHeights, MissingCalibration
        All are :class:`arsurf.errors.ScanError`; :class:`arsurf.errors.MissingDependency` when
        the format needs an optional package (``pip install 'arsurf[formats]'``).

    Examples
    --------
    >>> scan = load_scan("Veeco_20160622.003")  # doctest: +SKIP
    >>> scan.metadata["format"], scan.channel  # doctest: +SKIP
    ('nanoscope', 'Height (Retrace)')
    """
    path = Path(path)
    head = _head(path)
    fmt = detect_format(path, head)
    mod = _module(fmt)
    options = {k: v for k, v in (("dx", dx), ("dy", dy), ("xy_unit", xy_unit), ("z_unit", z_unit), ("frame", frame))
               if v is not None}
    accepted = set(inspect.signature(mod.read).parameters)
    extra = sorted(set(options) - accepted)
    if extra == ["frame"]:
        raise ScanError(f"{path}: the {fmt} format holds one image per channel, not a movie; frame applies only to "
                        f"movies (.asd, .h5-jpk); remove it")
    if extra:
        raise ScanError(
            f"{path}: the {fmt} format states its own calibration; {', '.join(extra)} apply only to formats "
            f"that do not (ASCII matrix/XYZ, .npy/.npz); remove them"
        )
    try:
        scan = mod.read(path, channel, **options)
    except (ScanError, MissingDependency):
        raise
    except ArsurfError as exc:
        raise CorruptScan(f"{path}: cannot be read as {fmt}: {exc}") from exc
    except MemoryError as exc:
        raise CorruptScan(f"{path}: cannot be read as {fmt}: the header asks for more memory than exists") from exc
    except RecursionError as exc:
        raise CorruptScan(f"{path}: cannot be read as {fmt}: structure nested too deeply (corrupt file)") from exc
    except Exception as exc:  # third-party parsers raise anything on damaged files: wrap it
        text = str(exc)
        text = text if len(text) <= 200 else text[:200] + "..."
        raise CorruptScan(
            f"{path}: cannot be read as {fmt} ({type(exc).__name__}: {text}); the file is truncated or corrupt"
        ) from exc
    finite = int(np.isfinite(scan.heights).sum())
    if finite == 0:
        raise InvalidHeights(
            f"{path}: channel {scan.channel!r} has no finite pixel (all {scan.heights.size} are NaN); "
            f"choose another channel from {scan.metadata.get('channels')}"
        )
    return scan


def save_scan(scan, path: str | os.PathLike) -> Path:
    """Write ``scan`` to ``path``; the format comes from the extension.

    ``.npz``: heights float64 + metadata as JSON, bit-exact round trip. ``.npy``: the heights
    array plus a ``<file>.npy.json`` sidecar with spacing and metadata, bit-exact. ``.gsf``:
    Gwyddion Simple Field, float32 by the spec (round trip exact to float32, i.e. relative
    2**-24; spacings exact), readable by Gwyddion; rows are written top-first as Gwyddion
    expects and flipped back by :func:`load_scan`.

    Returns
    -------
    Path
        The written file.

    Raises
    ------
    UnknownFormat
        The extension is not one of ``.gsf``, ``.npz``, ``.npy``.

    Examples
    --------
    >>> save_scan(scan, "out.npz")  # doctest: +SKIP
    """
    from arsurf.scan.scan import Scan

    if not isinstance(scan, Scan):
        raise InvalidHeights(f"save_scan needs an arsurf Scan (got {type(scan).__name__}); build one with arsurf.Scan")
    path = Path(path)
    fmt = _WRITERS.get(path.suffix.lower())
    if fmt is None:
        raise UnknownFormat(
            f"cannot save {str(path)!r}: the extension {path.suffix or '(none)'!r} is not a writable format; "
            f"use one of {sorted(_WRITERS)}"
        )
    _module(fmt).write(scan, path)
    return path
