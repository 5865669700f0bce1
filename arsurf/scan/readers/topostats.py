"""TopoStats ``.topostats`` reader (HDF5: the processed images TopoStats users already have).

Library: h5py (a core dependency). TopoStats writes one HDF5 file per image with ``image``
(float64, nanometres), ``pixel_to_nm_scaling`` (nm per pixel, square pixels) and
``topostats_file_version``; newer versions add groups (grain masks, traces) that are not images
of the surface and are not read. No maintained reader of the field reads these files (AFMReader
writes them).

Orientation: TopoStats keeps images in the display order of its plots (row 0 at the top), so rows
are flipped to arsurf's row 0 = bottom. Validation before any array is read: the HDF5 signature,
the ``image`` dataset's shape and dtype (2-D, numeric, at most as many bytes as the file holds),
a finite positive scaling.
"""
from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np

from arsurf.errors import CorruptScan
from arsurf.scan.readers._common import Channel, check_shape, make_scan, open_scan_hdf5, select_channel

EXTENSIONS = (".topostats",)
FORMAT = "topostats"


def sniff(head: bytes) -> bool:
    """False: an HDF5 signature alone does not say TopoStats (the extension does)."""
    return False


def read(path: Path | str, channel: str | None = None):
    """Read the ``image`` of a TopoStats file, in metres (the file stores nanometres)."""
    import h5py

    path = Path(path)
    size = path.stat().st_size
    try:
        with contextlib.ExitStack() as stack:
            f = stack.enter_context(open_scan_hdf5(path, "a TopoStats file"))
            if "image" not in f or not isinstance(f["image"], h5py.Dataset):
                raise CorruptScan(f"{path}: no 'image' dataset (keys: {sorted(f.keys())[:10]})")
            ds = f["image"]
            if ds.ndim != 2 or ds.dtype.kind not in "fiu":
                raise CorruptScan(f"{path}: 'image' is {ds.dtype} of shape {ds.shape}, not a 2-D numeric image")
            ny, nx = (int(n) for n in ds.shape)
            check_shape(path, nx, ny)
            if nx * ny * ds.dtype.itemsize > 64 * size + (1 << 20):  # compression aside, bounded by the file
                raise CorruptScan(f"{path}: 'image' claims {nx}x{ny} values, more than the file can hold")
            if "pixel_to_nm_scaling" not in f:
                raise CorruptScan(f"{path}: no 'pixel_to_nm_scaling' (nm per pixel)")
            scaling = f["pixel_to_nm_scaling"][()]
            try:
                nm = float(np.asarray(scaling).reshape(-1)[0])
            except (TypeError, ValueError, IndexError):
                raise CorruptScan(f"{path}: pixel_to_nm_scaling is not a number ({scaling!r})") from None
            data = np.asarray(ds[()], dtype=np.float64)
            version = f["topostats_file_version"][()] if "topostats_file_version" in f else None
    except OSError as exc:  # h5py's errors for a damaged file
        raise CorruptScan(f"{path}: the HDF5 structure is damaged ({str(exc).splitlines()[0]})") from None
    chan = Channel("image", key=0, unit="nm", height=True)  # TopoStats' images are topography
    chan = select_channel(path, [chan], channel)
    return make_scan(path, FORMAT, data[::-1], nm * 1e-9, nm * 1e-9, chan, [chan], rows_flipped=True,
                     z_factor=1e-9, z_unit="m",
                     instrument={"software": "TopoStats",
                                 "version": None if version is None else float(np.asarray(version).reshape(-1)[0])})
