"""Readers of issue #14 §3: Nanosurf ``.nhf``, NT-MDT ``.mdt``, high-speed AFM ``.asd`` (a movie).

The checks that count compare with the formats' reference readers (tests/support/data/SOURCES.md):

- ``.nhf``: a verbatim excerpt of Nanosurf's own example file; heights equal the values Nanosurf's
  reader (``nanosurf.utils.io.nhf_reader`` 2.0.7) gives, and the ``Position Z`` channel equals
  Nanosurf's own Gwyddion export of the same measurement pixel for pixel; a v2 file built by the
  vendor's rules (calibration graph, NaN fill value) gives the values its rules define.
- ``.mdt``: a verbatim excerpt (one MDA frame) of SciFiReaders' test file, at the three pixels
  SciFiReaders' test suite publishes; scanned-image frames written by Gwyddion's layout.
- ``.asd``: pixel sizes and frame counts that AFMReader's test suite publishes and heights equal
  to libasd's on the real movies when they are present (they are GPL and 16-37 MB: not bundled);
  always, movies of versions 0, 1 and 2 written by the layout, against the conversion formula.
"""
from __future__ import annotations

import json
import os
import shutil
import struct
from pathlib import Path

import h5py
import numpy as np
import pytest
from tests.support.real_scans import REAL_SCANS
from tests.support.format_samples import ER, PH, TP, asd_file, asd_frames, mdt_file, mdt_scanned_frame, samples

from arsurf.cli import main
from arsurf.errors import ChannelNotFound, CorruptScan, ScanError
from arsurf.scan.io import detect_format, load_scan

DATA = Path(__file__).resolve().parents[1] / "support" / "data"
NHF = DATA / "nanosurf_wavemode_excerpt.nhf"
NHF_GWY = DATA / "nanosurf_wavemode_export.gwy"
MDA = DATA / "ntmdt_mda_excerpt.mdt"
#: where the real .asd movies of AFMReader's sdist may be (SOURCES.md of ../shared/scans-real)
ASD_DIRS = [Path(p) for p in os.environ.get("ARSURF_EXTRA_SCANS", "").split(os.pathsep) if p] + [REAL_SCANS]


def test_synthetic_samples_are_up_to_date():
    for name, blob in samples().items():
        assert (DATA / name).read_bytes() == blob, f"rerun: python tests/support/format_samples.py ({name})"


# ------------------------------------------------------------------------------------------ nhf
def test_nanosurf_nhf_heights_equal_nanosurfs_reader():
    """Values of Nanosurf's nhf_reader 2.0.7 on SBS-PS_example_data.nhf, segment Forward,
    channel Topography (``read_channel(..., as_matrix=True)``, whose row 0 is the top)."""
    s = load_scan(NHF)
    assert s.metadata["format"] == "nhf" and s.channel == "Topography (Forward)" and s.shape == (100, 100)
    assert s.dx == pytest.approx(1e-7, rel=1e-12) and s.dy == pytest.approx(1e-7, rel=1e-12)
    assert s.metadata["z_unit"] == "m" and s.metadata["direction"] == "forward"
    h = s.heights
    assert h.min() == 2.6679197254904047e-06 and h.max() == 2.839820193684513e-06
    assert h[-1, 0] == 2.7586874636104366e-06  # the vendor's [0, 0] (top-left)
    assert h.sum() == pytest.approx(0.02757538556561024, rel=1e-12)
    assert s.metadata["instrument"]["file_version"] == "1.1"


def test_nanosurf_position_z_equals_nanosurfs_gwyddion_export():
    """Nanosurf's WaveMode app exported the same measurement to Gwyddion (its 'Topography' is the
    Z sensor, ``Position Z``): equal pixel for pixel, so orientation and scaling agree."""
    s = load_scan(NHF, "Position Z (Forward)")
    g = load_scan(NHF_GWY, "Topography")
    assert s.shape == g.shape and s.dx == pytest.approx(g.dx, rel=1e-12)
    assert np.abs(s.heights - g.heights).max() < 1e-20


def test_nanosurf_channels_units_and_directions():
    s = load_scan(NHF, "Z-Controller In (Backward)")
    assert s.metadata["z_unit"] == "V" and s.metadata["direction"] == "backward"
    assert s.metadata["channel_units"]["Position Z (Forward)"] == "m"
    assert "NMA Free Wave" not in " ".join(s.metadata["channels"])  # a curve, not an image
    raw = load_scan(NHF, "nma_interaction_min (Forward)")  # no calibration in the file: raw levels, no unit
    assert raw.metadata["z_unit"] == "" and np.all(raw.heights == np.round(raw.heights))


def _nhf_v2(path: Path, raw: np.ndarray, *, lines=12, points=20, xr=5e-6, yr=2.5e-6):
    """A version-2 file by Nanosurf's rules: rect_axis_size = (lines, points), rect_axis_range =
    (y, x), signal calibration, a calibration graph volts -> newtons, HDF5 fill value = NaN."""
    with h5py.File(path, "w") as f:
        f.attrs["nsf_file_version_major"], f.attrs["nsf_file_version_minor"] = np.uint32(2), np.uint32(0)
        cal = f.create_group("calibration")
        cal.attrs["group_type"] = "calibration"
        node = cal.create_dataset("node_0", data=np.zeros(1))
        node.attrs.update({"signal_calibration_id": "c0", "signal_source_id": "defl_raw", "signal_sink_id": "defl_N",
                           "signal_source_unit": "Volt (V)", "signal_sink_unit": "Newton (N)",
                           "signal_mapping_type": "linear", "signal_mapping_parameters": np.array([2e-9, 1e-10]),
                           "signal_invertibility": "right"})
        m = f.create_group("measurement_0")
        m.attrs.update({"measurement_name": "Image 1", "group_type": "image_line_based",
                        "rect_axis_size": np.array([lines, points], dtype=np.uint32),
                        "rect_axis_range": np.array([yr, xr])})
        for i, name in enumerate(("Forward", "Backward")):
            seg = m.create_group(f"segment_{i}")
            seg.attrs["segment_name"] = name
            d = seg.create_dataset("dataset_0", data=raw.astype(np.int32).ravel(), fillvalue=np.int32(-2**31))
            d.attrs.update({"signal_name": "Topography", "dataset_element_type": "int32", "signal_unit": "Meter (m)",
                            "signal_calibration_min": -1e-6, "signal_calibration_max": 1e-6,
                            "signal_calibration_unit": "Meter (m)", "signal_id": "topo", "signal_selected": "topo"})
            e = seg.create_dataset("dataset_1", data=(raw // 1000).astype(np.int16).ravel(), fillvalue=np.int16(-2**15))
            e.attrs.update({"signal_name": "Deflection", "dataset_element_type": "int16", "signal_unit": "Volt (V)",
                            "signal_calibration_min": -10.0, "signal_calibration_max": 10.0,
                            "signal_calibration_unit": "Volt (V)", "signal_id": "defl_raw", "signal_selected": "defl_N"})


def test_nanosurf_v2_rules(tmp_path):
    rng = np.random.default_rng(1)
    raw = rng.integers(-2**30, 2**30, (12, 20))
    raw[3, 4] = -2**31  # the fill value: a missing pixel
    p = tmp_path / "v2.nhf"
    _nhf_v2(p, raw)
    assert detect_format(p) == "nhf"
    s = load_scan(p)
    tmin, tmax = -2.0**31 + 1, 2.0**31 - 1
    want = (raw - tmin) * (2e-6 / (tmax - tmin)) - 1e-6
    want[3, 4] = np.nan
    np.testing.assert_array_equal(s.heights, want)
    assert s.shape == (12, 20) and s.dx == pytest.approx(5e-6 / 20) and s.dy == pytest.approx(2.5e-6 / 12)
    d = load_scan(p, "Deflection (Backward)")  # shown in newtons through the calibration graph, from the stored values
    assert d.metadata["z_unit"] == "N"
    np.testing.assert_allclose(d.heights, 2e-9 * (raw // 1000).astype(np.int16) + 1e-10, rtol=1e-15)
    # the values Nanosurf's nhf_reader 2.0.7 gives for this file (checked once against it): same as above
    assert np.isnan(s.heights).sum() == 1


def test_nanosurf_damaged_calibration_is_refused(tmp_path):
    p = tmp_path / "v2.nhf"
    _nhf_v2(p, np.arange(240).reshape(12, 20))
    with h5py.File(p, "r+") as f:
        f["measurement_0/segment_0/dataset_0"].attrs["signal_calibration_max"] = -1e-6  # = min: empty range
        f["measurement_0/segment_1/dataset_1"].attrs["signal_selected"] = "nowhere"
        f["measurement_0"].attrs["rect_axis_size"] = np.array([12, 20], dtype=np.uint32)
    with pytest.raises(CorruptScan, match="signal_calibration_min..signal_calibration_max"):
        load_scan(p)
    with pytest.raises(CorruptScan, match="no calibration leads"):
        load_scan(p, "Deflection (Backward)")
    with h5py.File(p, "r+") as f:
        f.attrs["nsf_file_version_major"] = np.uint32(7)
    with pytest.raises(CorruptScan, match="version 7.0 is not supported"):
        load_scan(p)


# ------------------------------------------------------------------------------------------ mdt
def test_ntmdt_mda_frame_equals_scifireaders_published_values():
    """SciFiReaders' test_mdt.py publishes ``image[134, 12]``, ``[18, 0]``, ``[206, -5]`` of
    '001_1F:Iprobe' in nA; their image is ``rot90(stored, k=3)`` of the stored (bottom-first)
    array, i.e. their ``[i, j]`` is our ``[255 - j, i]``."""
    s = load_scan(MDA)
    assert s.metadata["format"] == "mdt" and s.channel == "1F:Iprobe" and s.shape == (256, 256)
    assert s.metadata["z_unit"] == "A" and s.metadata["direction"] == "forward"
    assert s.dx == pytest.approx(0.011767974683082529e-6, rel=1e-12) and s.dy == s.dx
    for (i, j, nanoamps) in [(134, 12, -0.021743940479999998), (18, 0, -0.00267030848), (206, -5, -0.02784750272)]:
        assert s.heights[255 - (j % 256), i] == pytest.approx(nanoamps * 1e-9, rel=1e-12)
    assert s.metadata["frames"] == ["0: text", "1: MDA"]
    assert s.metadata["channel_units"] == {"1F:Iprobe": "A"}


def test_ntmdt_scanned_frames_by_gwyddions_layout():
    p = DATA / "synthetic_scanned.mdt"
    s = load_scan(p)
    assert s.channel == "Height" and s.metadata["channels"] == ["Height", "Phase"]
    rng = np.random.default_rng(11)
    y, x = np.mgrid[0:40, 0:48]
    raw = (300 * np.sin(x / 5.0) + 40 * y + rng.integers(-20, 21, (40, 48))).astype(np.int16)
    np.testing.assert_allclose(s.heights, (np.float32(-50.0) + np.float32(0.02) * raw.astype(float)) * 1e-9,
                               rtol=1e-12)  # value = z_offset + z_step * raw, nm; bottom line stored first
    assert s.dx == pytest.approx(12.5e-9) and s.dy == pytest.approx(25e-9)
    ph = load_scan(p, "phase")
    assert ph.metadata["z_unit"] == "deg" and ph.metadata["adc_mode"] == "Phase1"


@pytest.mark.parametrize("z_unit, factor, step", [(-2, 1e-6, 1e-4), (0, 1e-10, 1e-4), (-5, 1.0, 1e-8)])
def test_ntmdt_units_from_the_frame_header(tmp_path, z_unit, factor, step):
    raw = np.arange(12, dtype=np.int16).reshape(3, 4)
    p = tmp_path / "u.mdt"
    p.write_bytes(mdt_file([mdt_scanned_frame(raw, title="", z_step=step, z_unit=z_unit, x_step=3.0, xy_unit=-2)]))
    s = load_scan(p)
    assert s.channel == "Height"  # untitled: named by its ADC mode
    np.testing.assert_allclose(s.heights, float(np.float32(step)) * raw.astype(float) * factor, rtol=1e-12)
    assert s.dx == pytest.approx(3e-6)


def test_ntmdt_height_beyond_any_z_travel_is_refused(tmp_path):
    p = tmp_path / "m.mdt"
    p.write_bytes(mdt_file([mdt_scanned_frame(np.full((3, 4), 1000, np.int16), z_step=1e-4, z_unit=-5)]))
    with pytest.raises(CorruptScan, match="z travel"):
        load_scan(p)


def test_ntmdt_damaged_headers_are_refused(tmp_path):
    good = (DATA / "synthetic_scanned.mdt").read_bytes()
    f1 = 33 + struct.unpack_from("<I", good, 33)[0]  # the first scanned frame, after the text frame
    cases = {
        "size": (4, struct.pack("<I", len(good))),  # file size field
        "unit": (f1 + 22 + 28, struct.pack("<h", 77)),  # z unit code
        "pixels": (f1 + 22 + 107 + 2, struct.pack("<H", 60000)),  # frame-mode xres
        "zscale": (f1 + 22 + 24, struct.pack("<f", 0.0)),  # z step
        "xscale": (f1 + 22 + 4, struct.pack("<f", float("nan"))),  # x step
    }
    for what, (off, patch) in cases.items():
        b = bytearray(good)
        b[off : off + len(patch)] = patch
        p = tmp_path / f"{what}.mdt"
        p.write_bytes(bytes(b))
        with pytest.raises(CorruptScan):
            load_scan(p)
    p = tmp_path / "cut.mdt"
    p.write_bytes(good[:-100])
    with pytest.raises(CorruptScan, match="truncated"):
        load_scan(p)


# ------------------------------------------------------------------------------------------ asd
def _asd_expected(raw, coef_nm_per_v, volts=5.0, bits=12):
    return coef_nm_per_v * (volts - 2.0 * raw.astype(float) * volts / 2**bits)


@pytest.mark.parametrize("version", [0, 1, 2])
def test_asd_movies_by_the_layout(version):
    p = DATA / f"synthetic_v{version}.asd"
    assert detect_format(p) == "asd"
    frames = asd_frames()
    for k in range(3):
        s = load_scan(p, frame=k)
        assert s.channel == "Topography" and s.metadata["frame"] == k and s.metadata["frames"] == 3
        np.testing.assert_allclose(s.heights, _asd_expected(frames[k], 2.0 * 45.0) * 1e-9, rtol=1e-12)
        assert s.dx == pytest.approx(200e-9 / 24) and s.dy == pytest.approx(100e-9 / 16)
    if version == 0:
        ph = load_scan(p, "PH", frame=2)
        assert ph.metadata["z_unit"] == "deg"
        np.testing.assert_allclose(ph.heights, _asd_expected(asd_frames(seed=9)[2] // 3, -1.5), rtol=1e-12)
    if version == 1:
        er = load_scan(p, "Error", frame=1)
        assert er.metadata["z_unit"] == "m" and not er.metadata["channels"] == ["Topography"]
        np.testing.assert_allclose(er.heights, _asd_expected(asd_frames(seed=9)[1] // 3, -8.5) * 1e-9, rtol=1e-12)


def test_asd_equals_libasd_on_the_bundled_movies():
    libasd = pytest.importorskip("libasd", reason="libasd (optional reference reader, MIT) is not installed")
    for version in (0, 1, 2):
        p = DATA / f"synthetic_v{version}.asd"
        data = libasd.read_asd(str(p))
        chans = data.channels if hasattr(data, "channels") else [data.frames]
        names = load_scan(p).metadata["channels"]
        for ci, frames in enumerate(chans):
            for k, fr in enumerate(frames):
                s = load_scan(p, names[ci], frame=k)
                scale = 1e9 if s.metadata["z_unit"] == "m" else 1.0
                np.testing.assert_allclose(s.heights * scale, np.asarray(fr.image()), rtol=1e-12, atol=1e-12)


def _real_asd(name: str) -> Path:
    for d in ASD_DIRS:
        if (d / name).is_file():
            return d / name
    pytest.skip(f"{name} (in AFMReader's sdist: GPL, tens of MB, not bundled) is not in $ARSURF_EXTRA_SCANS or "
                f"{REAL_SCANS}: see ../shared/scans-real/SOURCES.md to fetch it")


@pytest.mark.parametrize("name, frames, nm_per_pixel", [("sample_0.asd", 142, 0.78125), ("sample_1.asd", 197, 2.0)])
def test_real_asd_movies_match_afmreaders_published_values(name, frames, nm_per_pixel):
    """AFMReader's tests/test_asd.py: number of frames and pixel_to_nm_scaling of channel TP."""
    p = _real_asd(name)
    s = load_scan(p, "TP", frame=frames - 1)
    assert s.metadata["frames"] == frames and s.metadata["frame"] == frames - 1
    assert s.dx * 1e9 == pytest.approx(nm_per_pixel, rel=1e-12)
    libasd = pytest.importorskip("libasd", reason="libasd (optional reference reader) is not installed")
    ref = libasd.read_asd(str(p)).channels[0]
    for k in (0, frames // 2, frames - 1):
        np.testing.assert_allclose(load_scan(p, frame=k).heights * 1e9, np.asarray(ref[k].image()), rtol=1e-7)


def test_asd_frame_and_channel_errors(tmp_path):
    p = DATA / "synthetic_v1.asd"
    with pytest.raises(ChannelNotFound, match=r"frame 3 is not in .*frames 0\.\.2"):
        load_scan(p, frame=3)
    with pytest.raises(ChannelNotFound, match="Phase"):
        load_scan(p, "Phase")
    with pytest.raises(ScanError, match="frame applies only to movies"):
        load_scan(MDA, frame=1)
    uncalibrated = tmp_path / "zero.asd"
    uncalibrated.write_bytes(asd_file(0, [(TP, asd_frames()), (PH, asd_frames())], phase_sensitivity=0.0))
    with pytest.raises(CorruptScan, match="phase sensitivity of 0"):
        load_scan(uncalibrated, "Phase")
    assert load_scan(uncalibrated).channel == "Topography"


def test_asd_truncated_or_edited_headers_are_refused(tmp_path):
    good = (DATA / "synthetic_v1.asd").read_bytes()
    for cut in (4, 100, 170, len(good) - 1):
        p = tmp_path / f"cut{cut}.asd"
        p.write_bytes(good[:cut])
        with pytest.raises(ScanError):
            load_scan(p)
    for off, value in ((36, 10**8), (48, -4), (133, 0x7), (137, 40), (161, float("nan"))):
        b = bytearray(good)
        struct.pack_into("<f" if isinstance(value, float) else "<i", b, off, value)
        p = tmp_path / f"edit{off}.asd"
        p.write_bytes(bytes(b))
        with pytest.raises(CorruptScan):
            load_scan(p)


def test_asd_sniffing_leaves_the_other_formats_alone(real_scans_dir):
    for p in sorted(real_scans_dir.iterdir()):
        if p.suffix.lower() not in (".md",):
            assert detect_format(p) != "asd", p.name


def test_formats_detected_by_content_under_any_name(tmp_path):
    for src, fmt in ((NHF, "nhf"), (MDA, "mdt"), (DATA / "synthetic_v0.asd", "asd")):
        dst = tmp_path / f"renamed{fmt}.dat"
        shutil.copy(src, dst)
        assert detect_format(dst) == fmt
        assert load_scan(dst).metadata["format"] == fmt


# ------------------------------------------------------------------------------------------ CLI
def test_cli_info_and_convert_reach_the_new_formats(capsys, tmp_path):
    assert main(["info", str(DATA / "synthetic_v2.asd"), "--frame", "2", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["format"] == "asd" and out["channel"] == "Topography" and out["frame"].startswith("2 of 0..2")
    assert main(["info", str(NHF), "--channel", "Z-Controller In (Forward)", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert "z_min_V" in out and out["channel_units"]["Topography (Forward)"] == "m"
    dst = tmp_path / "height.gsf"
    assert main(["convert", str(DATA / "synthetic_scanned.mdt"), "-o", str(dst)]) == 0
    capsys.readouterr()
    np.testing.assert_allclose(load_scan(dst).heights, load_scan(DATA / "synthetic_scanned.mdt").heights, rtol=1e-6)


def test_cli_frame_errors_are_one_line(capsys):
    code = main(["info", str(DATA / "synthetic_v0.asd"), "--frame", "7"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "frame 7" in err and "0..2" in err, err
    code = main(["info", str(MDA), "--frame", "1"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "movies" in err, err
    with pytest.raises(SystemExit) as info:
        main(["info", str(MDA), "--frame", "-1"])
    assert info.value.code == 2 and "--frame" in capsys.readouterr().err
