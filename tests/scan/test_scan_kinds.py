"""Files arsurf does not read are named for what they are (issue #30, "Traps"): a binary file with a
text-table extension is not parsed as text, a text file renamed .npz does not get numpy's pickle
advice, valid files of other kinds (Gwyddion 1.x, force curves, RGB TIFFs, Nanonis grids, a fitted
surface) raise :class:`UnsupportedScan` saying what they are, not :class:`CorruptScan`."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from arsurf.errors import CorruptScan, ScanError, UnknownFormat, UnsupportedScan
from arsurf.scan import synthetic
from arsurf.scan.io import load_scan, save_scan
from arsurf.spline.fit import fit_surface
from arsurf.spline.storage import save_surface


def _spiepy_raw(path, shape=(32, 48)):
    """SPIEPy's raw layout: int32 rows, int32 columns, then float64 heights (no units, no spacing)."""
    heights = np.random.default_rng(1).normal(size=shape)
    path.write_bytes(struct.pack("<ii", *shape) + heights.astype("<f8").tobytes())
    return path


def test_a_binary_dat_is_not_read_as_text(tmp_path):
    with pytest.raises(UnknownFormat) as info:
        load_scan(_spiepy_raw(tmp_path / "raw.dat"), dx=1e-9, dy=1e-9, z_unit="nm")
    text = str(info.value)
    assert "binary file" in text and "ragged" not in text and len(text.splitlines()) == 1, text


def test_a_text_file_renamed_npz_or_npy_gets_no_pickle_advice(tmp_path):
    for name in ("notes.npz", "notes.npy"):
        p = tmp_path / name
        p.write_text("these are notes, not an array\n" * 3)
        with pytest.raises(CorruptScan) as info:
            load_scan(p, dx=1e-9, dy=1e-9)
        assert "pickle" not in str(info.value) and "not a NumPy" in str(info.value), str(info.value)


def _tiff(path, data, photometric):
    tifffile = pytest.importorskip("tifffile")
    tifffile.imwrite(path, data, photometric=photometric)
    return path


@pytest.mark.parametrize("name, content, what", [
    ("old.gwy", b"GWYOGwyContainer\x00" + b"\x00" * 64, "Gwyddion 1.x"),
    ("grid.3ds", b'Grid dim="16 x 16"\r\nGrid settings=0;0;1E-8;1E-8;0\r\n:HEADER_END:\r\n' + b"\x00" * 64,
     "Nanonis grid spectroscopy"),
    ("curve.dat", b"Experiment\tbias spectroscopy\r\nDate\t01.01.2020\r\n\r\n[DATA]\r\nBias (V)\tCurrent (A)\r\n",
     "Nanonis spectroscopy"),
    ("f.001", b"\\*Force file list\r\n\\Version: 0x09200000\r\n\\*File list end\r\n" + b"\x00" * 64,
     "force-curve"),
])
def test_files_of_other_kinds_are_unsupported_not_corrupt(tmp_path, name, content, what):
    p = tmp_path / name
    p.write_bytes(content)
    with pytest.raises(UnsupportedScan, match=what):
        load_scan(p)


def test_an_rgb_tiff_is_a_picture_not_a_corrupt_scan(tmp_path):
    rgb = _tiff(tmp_path / "photo.tif", np.zeros((16, 16, 3), np.uint8), "rgb")
    with pytest.raises(UnsupportedScan, match="RGB TIFF picture"):
        load_scan(rgb)
    grey = _tiff(tmp_path / "grey.tiff", np.zeros((16, 16), np.float32), "minisblack")
    with pytest.raises(UnsupportedScan, match="without the Park Systems or JPK tags"):
        load_scan(grey)


def test_a_fitted_surface_is_named_a_surface(tmp_path):
    scan = synthetic.sinusoid(shape=(12, 12), pixel=5e-9, amplitude=2e-9, period=40e-9)
    p = save_surface(fit_surface(scan), tmp_path / "fit.npz")
    with pytest.raises(UnsupportedScan, match="a fitted surface"):
        load_scan(p)
    save_scan(scan, tmp_path / "scan.npz")  # an .npz scan is still one
    assert load_scan(tmp_path / "scan.npz").shape == (12, 12)


def test_unsupported_is_a_scan_error_but_not_corrupt():
    assert issubclass(UnsupportedScan, ScanError) and not issubclass(UnsupportedScan, CorruptScan)
