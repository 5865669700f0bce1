"""JPK HDF5 ``.h5-jpk`` reader: the real sample (SOURCES.md), AFMReader's recipe as the
reference, the calibration chain, frames, content detection, and damaged files refused with a
one-line ScanError naming the field."""
from __future__ import annotations

import shutil

import h5py
import numpy as np
import pytest
from tests.support.real_scans import real_scan_path

from arsurf.errors import ScanError
from arsurf.scan.io import detect_format, load_scan

pytestmark = pytest.mark.realscan
NAME = "sample_0.h5-jpk"


def afmreader_recipe(path, group, dataset, frame):
    """AFMReader h5_jpk.load_h5jpk, written out: net-encoder multiplier/offset on the raw
    integers, one column per frame, reshaped (ilength, ilength) with the first stored line
    first (AFMReader then flips it for display, which we do not: row 0 = bottom)."""
    with h5py.File(path, "r") as f:
        m = f["Measurement_000"]
        g = m[group]
        raw = g[dataset][:, frame].astype(np.float64)
        img = raw * float(g.attrs["net-encoder.scaling.multiplier"]) + float(g.attrs["net-encoder.scaling.offset"])
        n = int(m.attrs["position-pattern.grid.ilength"])
        return img.reshape(n, n), float(m.attrs["position-pattern.grid.ulength"]) / n


def test_real_h5jpk_reads_as_afmreader_does():
    path = real_scan_path(NAME)
    s = load_scan(path)
    assert s.metadata["format"] == "h5-jpk" and s.channel == "Height (trace)"
    assert s.shape == (128, 128) and s.dx == pytest.approx(150e-9 / 128, rel=1e-12) and s.dy == s.dx
    ref, spacing = afmreader_recipe(path, "Channel_001", "Height", 0)
    np.testing.assert_allclose(s.heights, ref, rtol=1e-12, atol=1e-21)
    assert s.dx == pytest.approx(spacing, rel=1e-12)
    # a height image of a surface: tens of nm of relief at most, within the 1.44 um z range
    assert 1e-9 < np.ptp(s.heights) < 100e-9 and 0 < s.heights.min() < 1.44e-6
    names = s.metadata["channels"]
    assert len(names) == 9 * 4 and len({n.lower() for n in names}) == len(names)
    assert s.metadata["channel_units"]["Phase (trace)"] == "deg" and s.metadata["channel_units"]["Error (trace)"] == "m"


def test_every_frame_is_selectable_and_frames_differ():
    path = real_scan_path(NAME)
    first = load_scan(path, "Height (retrace)")
    last = load_scan(path, "Height (retrace) frame 3")
    ref, _ = afmreader_recipe(path, "Channel_003", "Height", 3)
    np.testing.assert_allclose(last.heights, ref, rtol=1e-12, atol=1e-21)
    assert last.metadata["frame"] == 3 and last.metadata["frames"] == 4
    assert last.metadata["frame_start_time_s"] > first.metadata["frame_start_time_s"]
    assert not np.array_equal(first.heights, last.heights)


def test_content_decides_the_format(tmp_path):
    src = real_scan_path(NAME)
    for fake in ("scan.bin", "scan.topostats", "scan"):
        dst = tmp_path / fake
        shutil.copy(src, dst)
        assert detect_format(dst) == "h5-jpk"
    topo = tmp_path / "t.h5-jpk"
    shutil.copy(real_scan_path("sample_0_1.topostats"), topo)
    assert detect_format(topo) == "topostats"


def _copy_with(tmp_path, edit):
    dst = tmp_path / "edited.h5-jpk"
    shutil.copy(real_scan_path(NAME), dst)
    with h5py.File(dst, "r+") as f:
        edit(f)
    return dst


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda f: f["Measurement_000"].attrs.__setitem__("position-pattern.grid.ilength", 100), "shape"),
        (lambda f: f["Measurement_000"].attrs.__setitem__("position-pattern.grid.ilength", -4), "not a valid size"),
        (lambda f: f["Measurement_000"].attrs.__setitem__("position-pattern.grid.ulength", np.nan), "not finite"),
        (lambda f: f["Measurement_000"].attrs.__setitem__("position-pattern.grid.ulength", 1e9), "outside any AFM"),
        (lambda f: f["Measurement_000/Channel_001"].attrs.__setitem__("conversion.calibrated.scaling.multiplier",
                                                                      0.5), "net encoder"),
        (lambda f: f["Measurement_000/Channel_001"].attrs.__setitem__("conversion.calibrated.base-calibration-slot",
                                                                      b"calibrated"), "loop"),
        (lambda f: f.attrs.__setitem__("file-format-info", b"SOMETHING ELSE"), "JPK SCAN"),
    ],
)
def test_damaged_fields_are_refused_naming_them(tmp_path, edit, match):
    p = _copy_with(tmp_path, edit)
    with pytest.raises(ScanError, match=match) as info:
        load_scan(p, "Height (trace)")
    assert "\n" not in str(info.value) and str(p) in str(info.value)


def test_truncated_copies_are_refused(tmp_path):
    data = real_scan_path(NAME).read_bytes()
    for frac in (0.05, 0.5, 0.9, 0.999):
        p = tmp_path / f"cut{frac}.h5-jpk"
        p.write_bytes(data[: int(len(data) * frac)])
        with pytest.raises(ScanError):
            load_scan(p)
