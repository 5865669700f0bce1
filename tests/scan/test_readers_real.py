"""Every reader on the real instrument files of ../shared/scans-real (figures from SOURCES.md).

SOURCES.md gives pixels, physical size and height range for each file; they are asserted to
the digits it states. Where a maintained third-party reader exists it is the reference.
"""
from __future__ import annotations

import shutil

from pathlib import Path

import numpy as np
import pytest
from tests.support.real_scans import real_scan_path

from arsurf.errors import ChannelNotFound
from arsurf.scan.io import load_scan

pytestmark = pytest.mark.realscan

GWY = "2024-10-24_104052_PH_wg_wv_No3_15slits_pol45deg_anal90deg_fine.gwy"
WEDGE = "2024-08-21_132732_PH_pmma_wedge_on_gold_thick_1600nm_Z_raw.gsf"
HOLES = "2018-02-09_1506_PH_dt20nmwindow1_Z_C.gsf"
FTIR = "2022-04-28_1518_PH_trivial_dose1,1_FB_horizontal_interf_synchronize_nanoFTIR_Z.gsf"
SXM = "STM_nanonis_generic_4_5.sxm"
IBW = "AR_20211011.ibw"
JPK = "sample_0.jpk"
VEECO = "Veeco_20160622.003"
PARK = "Park_20210916_034.tiff"


def sig(value: float, digits: int) -> float:
    """Half a unit in the last stated digit of ``value`` (SOURCES.md rounds to ``digits``)."""
    return 0.5 * 10 ** (np.floor(np.log10(abs(value))) - digits + 1)


def assert_range(scan, zmin, zmax, digits=6):
    h = scan.heights
    assert abs(np.nanmin(h) - zmin) <= sig(zmin, digits)
    assert abs(np.nanmax(h) - zmax) <= sig(zmax, digits)


def test_gwy_z_raw_matches_sources():
    s = load_scan(real_scan_path(GWY))
    assert s.channel == "Z raw"  # first forward topography channel (R-Z raw is the retrace)
    assert s.metadata["format"] == "gwy" and len(s.metadata["channels"]) == 58
    assert s.shape == (80, 80)
    assert s.dx == pytest.approx(4e-6 / 80, rel=1e-12) and s.dy == pytest.approx(4e-6 / 80, rel=1e-12)
    assert_range(s, 6.35775e-07, 8.0308e-07)
    assert (np.nanmax(s.heights) - np.nanmin(s.heights)) * 1e9 == pytest.approx(167.3, abs=0.05)
    assert s.metadata["nan_count"] == 0 and s.metadata["instrument"]["angle"] == "47"


def test_gwy_equals_gwyfile_for_every_channel():
    gwyfile = pytest.importorskip("gwyfile")
    path = real_scan_path(GWY)
    ref = gwyfile.util.get_datafields(gwyfile.load(str(path)))
    s0 = load_scan(path)
    assert sorted(s0.metadata["channels"]) == sorted(ref)
    for name in ["Z raw", "R-Z raw", "Z C", "R-Z C", "O2A raw", "M1P raw"]:
        s = load_scan(path, name)
        field = ref[name]
        np.testing.assert_array_equal(s.heights, field.data[::-1, :])  # rows flipped: row 0 = bottom
        assert s.dx == field["xreal"] / field["xres"]


def test_gwy_retrace_and_channel_errors():
    path = real_scan_path(GWY)
    s = load_scan(path, "r-z raw")  # case-insensitive
    assert s.channel == "R-Z raw" and s.metadata["direction"] == "backward"
    with pytest.raises(ChannelNotFound, match=r"'Height' is not in .*'Z raw'"):
        load_scan(path, "Height")


def test_gsf_wedge_non_square_pixels():
    s = load_scan(real_scan_path(WEDGE))
    assert s.shape == (200, 400)
    assert s.dx == pytest.approx(50e-9, rel=1e-12) and s.dy == pytest.approx(200e-9, rel=1e-12)
    assert s.size == pytest.approx(((400 - 1) * 50e-9, (200 - 1) * 200e-9))
    assert_range(s, 6.64123e-07, 9.03112e-07)
    assert (np.nanmax(s.heights) - np.nanmin(s.heights)) * 1e9 == pytest.approx(239.0, abs=0.05)
    assert s.metadata["header"]["YResIncomplete"] == "200"


def test_gsf_holes_matches_sources():
    s = load_scan(real_scan_path(HOLES))
    assert s.shape == (200, 200) and s.dx == pytest.approx(25e-9, rel=1e-12)
    assert_range(s, 1.16818e-06, 1.28755e-06)
    assert s.metadata["nan_count"] == 0


def test_gsf_equals_gsffile():
    gsffile = pytest.importorskip("gsffile")
    for name in (WEDGE, HOLES, FTIR):
        path = real_scan_path(name)
        data, meta = gsffile.read_gsf(path)
        s = load_scan(path)
        np.testing.assert_array_equal(s.heights, data[::-1, :].astype(np.float64))
        assert s.dx == pytest.approx(meta["XReal"] / data.shape[1], rel=1e-15)


def test_gsf_aborted_scan_keeps_nan_and_dropouts():
    s = load_scan(real_scan_path(FTIR))
    assert s.shape == (85, 400)
    assert s.metadata["nan_count"] == 311
    # the NaN pixels are in the last stored row, which is the top: our row ny-1... after the
    # flip (row 0 = bottom) the file's last row is our row 0
    assert np.isnan(s.heights[0]).sum() == 311 and np.isnan(s.heights[1:]).sum() == 0
    finite = s.heights[np.isfinite(s.heights)]
    assert abs(finite.max() - 3.83531e-07) <= sig(3.83531e-07, 6)
    assert finite.min() == pytest.approx(-1.3e-19, abs=0.05e-19)
    assert s.metadata["header"]["YResIncomplete"] == "100"


def test_sxm_forward_z():
    s = load_scan(real_scan_path(SXM))
    assert s.channel == "Z (forward)" and s.metadata["format"] == "sxm"
    assert s.metadata["channels"] == ["Z (forward)", "Z (backward)", "Current (forward)", "Current (backward)"]
    assert s.shape == (256, 256) and s.dx == pytest.approx(4e-9 / 256, rel=1e-12)
    assert_range(s, 9.14466e-09, 9.33976e-09)
    assert (s.heights.max() - s.heights.min()) * 1e9 == pytest.approx(0.195, abs=0.0005)
    assert s.metadata["rows_flipped"] is True  # SCAN_DIR down: first stored line is the top


def test_sxm_equals_pyspm_up_to_orientation():
    pytest.importorskip("pySPM")
    from pySPM.SXM import SXM as PySPMSXM

    path = real_scan_path(SXM)
    ref = PySPMSXM(str(path))
    fwd = ref.get_channel("Z").pixels
    bwd = ref.get_channel("Z", direction="backward").pixels
    np.testing.assert_array_equal(load_scan(path).heights, fwd[::-1, :])
    # backward: stored right to left, mirrored in x, then rows flipped like the forward image
    np.testing.assert_array_equal(load_scan(path, "Z (backward)").heights, bwd[::-1, ::-1])
    cur = load_scan(path, "Current (forward)")
    assert cur.metadata["z_unit"] == "A"


def test_ibw_height_retrace_and_pixel_spacing():
    s = load_scan(real_scan_path(IBW))
    assert s.channel == "HeightRetrace" and s.metadata["direction"] == "backward"
    assert s.metadata["channels"] == ["HeightRetrace", "AmplitudeRetrace", "PhaseRetrace", "ZSensorRetrace"]
    assert s.shape == (128, 128)
    # Asylum's sfA = ScanSize / (N - 1), not ScanSize / N
    assert s.dx == pytest.approx(4e-6 / 127, rel=1e-6) and s.dy == pytest.approx(4e-6 / 127, rel=1e-6)
    assert s.size[0] == pytest.approx(4e-6, rel=1e-6)
    assert_range(s, -3.24599e-08, 5.07883e-08)
    assert s.metadata["instrument"]["ScanSize"] == "4e-06"


def test_ibw_axis_order_is_transposed():
    igor2 = pytest.importorskip("igor2.binarywave")
    path = real_scan_path(IBW)
    w = igor2.load(str(path))["wave"]["wData"]
    np.testing.assert_array_equal(load_scan(path, "ZSensorRetrace").heights, w[:, :, 3].T)


def test_jpk_calibrated_height():
    path = real_scan_path(JPK)
    s = load_scan(path, "height (retrace)")
    assert s.shape == (256, 256)
    assert s.dx == pytest.approx(3.2691651420070083e-07 / 256, rel=1e-12)
    assert_range(s, 3.30311e-06, 3.35976e-06)
    assert (s.heights.max() - s.heights.min()) * 1e9 == pytest.approx(56.65, abs=0.005)
    assert s.metadata["calibration_slot"] == "calibrated"
    trace = load_scan(path)
    assert trace.channel == "height (trace)"  # forward is the default
    # AFMReader's expected sum of the calibrated height trace (SOURCES.md)
    assert trace.heights.sum() * 1e9 == pytest.approx(219242202.8, abs=0.1)


def test_veeco_z_scale_is_hard_value_over_2_16():
    s = load_scan(real_scan_path(VEECO))
    assert s.channel == "Height (Retrace)" and s.metadata["format"] == "nanoscope"
    assert s.shape == (512, 512)
    assert s.dx == pytest.approx(1.76908e-6 / 512, rel=1e-12)
    assert_range(s, -1.45608e-07, 1.3869e-08, digits=5)
    assert (s.heights.max() - s.heights.min()) * 1e9 == pytest.approx(159.5, abs=0.05)
    # the trap: raw * hard scale (V/LSB) * soft scale would give 428.57/41.60 = 10.3x this
    assert s.metadata["z_per_lsb"] == pytest.approx(41.60368 / 65536 * 7e-9, rel=1e-12)


def test_veeco_equals_pyspm():
    pytest.importorskip("pySPM")
    from pySPM.Bruker import Bruker

    path = real_scan_path(VEECO)
    ref = Bruker(str(path)).get_channel("Height", backward=True)
    np.testing.assert_allclose(load_scan(path).heights, ref.pixels * 1e-9, rtol=1e-12, atol=0)


def test_park_tiff():
    s = load_scan(real_scan_path(PARK))
    assert s.metadata["format"] == "park-tiff"
    assert s.shape == (256, 256) and s.dx == pytest.approx(2.5e-6 / 256, rel=1e-12)
    assert_range(s, -2.71321e-09, 9.24409e-09)
    assert (s.heights.max() - s.heights.min()) * 1e9 == pytest.approx(11.96, abs=0.005)
    assert s.metadata["data_gain"] < 0  # the gain is negative and must be kept


@pytest.mark.parametrize(
    "name, fake",
    [(VEECO, "scan.txt"), (WEDGE, "scan.gwy"), (SXM, "scan.ibw"), (IBW, "scan"), (PARK, "scan.jpk"), (JPK, "scan.tif"),
     (GWY, "scan.gsf")],
)
def test_content_wins_over_a_lying_extension(tmp_path, name, fake):
    src = real_scan_path(name)
    dst = tmp_path / fake
    shutil.copy(src, dst)
    a, b = load_scan(src), load_scan(dst)
    assert a.metadata["format"] == b.metadata["format"]
    np.testing.assert_array_equal(a.heights, b.heights)


@pytest.mark.parametrize("name, module", [(IBW, "igor2.binarywave"), (JPK, "tifffile"), (PARK, "tifffile")])
def test_missing_optional_package_names_the_extra(monkeypatch, name, module):
    import sys

    from arsurf.errors import MissingDependency

    path = real_scan_path(name)
    monkeypatch.setitem(sys.modules, module, None)  # makes "import module" raise ImportError
    with pytest.raises(MissingDependency, match=r"pip install 'arsurf\[formats\]'"):
        load_scan(path)


@pytest.mark.realscan
def test_bruker_v9_peakforce_file_reads_as_pyspm_does():
    """NanoScope v9.3 (sample_0.spm, SOURCES.md): keys written with capitals ("Scan Size"),
    4-byte images, a Height channel stored as int32 but scaled as 16-bit, Height Sensor the
    default; every channel selectable by the name listed."""
    from tests.support.real_scans import real_scan_path

    from arsurf.scan.io import load_scan

    path = real_scan_path("sample_0.spm")
    default = load_scan(path)
    assert default.shape == (1024, 1024)
    assert default.dx == pytest.approx(505.859e-9 / 1024, rel=1e-12)
    assert default.heights.min() == pytest.approx(132.126e-9, abs=1e-12)   # pySPM: 132.126-152.097 nm
    assert default.heights.max() == pytest.approx(152.097e-9, abs=1e-12)
    height = load_scan(path, channel="Height")
    assert height.heights.min() == pytest.approx(21.215e-9, abs=1e-12)     # pySPM: 21.215-37.125 nm
    assert height.heights.max() == pytest.approx(37.125e-9, abs=1e-12)
    names = default.metadata["channels"]
    assert len(names) == 8 and names[0] == "Height Sensor (Retrace)"
    for name in names:
        assert load_scan(path, channel=name).shape == (1024, 1024)


@pytest.mark.realscan
def test_topostats_file_reads_its_image_in_metres():
    """sample_0_1.topostats (SOURCES.md): 'image' (64, 64) in nm, pixel_to_nm_scaling 1.976 nm,
    rows flipped to row 0 = bottom; truncated copies are refused with a ScanError."""
    import h5py

    from arsurf.scan.io import load_scan

    path = real_scan_path("sample_0_1.topostats")
    s = load_scan(path)
    with h5py.File(path, "r") as f:
        ref = f["image"][()] * 1e-9
        nm = float(f["pixel_to_nm_scaling"][()])
    assert s.shape == (64, 64) and s.metadata["format"] == "topostats"
    assert s.dx == s.dy == pytest.approx(nm * 1e-9, rel=1e-15)
    np.testing.assert_array_equal(s.heights, ref[::-1])


@pytest.mark.realscan
@pytest.mark.parametrize("fraction", [0.0, 0.01, 0.1, 0.5, 0.9, 0.999])
def test_truncated_topostats_files_are_refused(tmp_path, fraction):
    from arsurf.errors import ScanError
    from arsurf.scan.io import load_scan

    data = Path(real_scan_path("sample_0_1.topostats")).read_bytes()
    cut = tmp_path / "cut.topostats"
    cut.write_bytes(data[: int(len(data) * fraction)])
    with pytest.raises(ScanError):
        load_scan(cut)
