"""Never a wrong surface from a damaged or odd file (issue #14 §6), one format rule at a time.

Each test breaks one rule a reader can check (data size against the header, a unit it knows, a
finite non-zero z scale, a plausible pixel spacing, where the data blocks sit) and asserts the
reader refuses it naming the field, or reads the channel in its own unit flagged as not a
height, which the fit then refuses unless asked. The damaged files are made from the real scans
of ../shared/scans-real or written by the format's rules here.
"""
from __future__ import annotations

import re
import struct
import subprocess
import sys
import textwrap
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from tests.support.real_scans import real_scan_path

import arsurf
from arsurf.errors import ChannelNotFound, CorruptScan, InvalidHeights, MissingCalibration, ScanError
from arsurf.scan.io import load_scan, save_scan
from arsurf.scan.scan import Scan

ROOT = Path(__file__).resolve().parents[2]


# ------------------------------------------------------------------------------------ GSF
def write_gsf(path, data, header: dict, *, extra: bytes = b"") -> Path:
    lines = ["Gwyddion Simple Field 1.0", *(f"{k} = {v}" for k, v in header.items())]
    head = ("\n".join(lines) + "\n").encode()
    path.write_bytes(head + b"\0" * (4 - len(head) % 4) + np.asarray(data, "<f4").tobytes() + extra)
    return path


GSF = {"XRes": 6, "YRes": 5, "XReal": 6e-8, "YReal": 5e-8, "XYUnits": "m", "ZUnits": "m"}


def test_a_gsf_in_volts_is_a_voltage_channel_that_is_never_fitted(tmp_path, rng):
    v = rng.normal(size=(5, 6))
    scan = load_scan(write_gsf(tmp_path / "v.gsf", v, {**GSF, "ZUnits": "V", "Title": "Z"}))
    assert scan.metadata["z_unit"] == "V" and scan.metadata["height"] is False
    np.testing.assert_allclose(scan.heights, v[::-1].astype(np.float32))  # volts, not metres
    with pytest.raises(InvalidHeights, match="'V', not heights"):
        arsurf.fit_surface(scan)
    with pytest.raises(InvalidHeights, match="cannot be used as a height"):
        scan.as_height()


def test_a_gsf_without_zunits_states_no_unit_and_is_not_taken_for_metres(tmp_path, rng):
    h = rng.normal(size=(5, 6)) * 1e-9
    p = write_gsf(tmp_path / "n.gsf", h, {k: v for k, v in GSF.items() if k != "ZUnits"})
    scan = load_scan(p)
    assert scan.metadata["z_unit"] == "" and scan.metadata["height"] is False
    with pytest.raises(InvalidHeights):
        arsurf.fit_surface(scan)
    named = load_scan(p, z_unit="nm")  # the caller states the unit the file does not
    assert named.metadata["z_unit"] == "m" and named.metadata["height"] is True
    np.testing.assert_allclose(named.heights, h[::-1].astype(np.float32) * 1e-9)
    with pytest.raises(ScanError, match="ZUnits"):
        load_scan(write_gsf(tmp_path / "m.gsf", h, GSF), z_unit="nm")


@pytest.mark.parametrize("edit, needle", [
    ({"YRes": 4}, "does not match the data"),        # YRes disagreeing with the data: Gwyddion's strict size
    ({"XRes": 3}, "does not match the data"),
    ({"YRes": 6}, "truncated or the header"),
])
def test_gsf_dimensions_must_match_the_data_exactly(tmp_path, rng, edit, needle):
    p = write_gsf(tmp_path / "d.gsf", rng.normal(size=(5, 6)) * 1e-9, {**GSF, **edit})
    with pytest.raises(CorruptScan, match=needle):
        load_scan(p)


def test_gsf_trailing_bytes_and_bad_padding_are_refused(tmp_path, rng):
    h = rng.normal(size=(5, 6)) * 1e-9
    with pytest.raises(CorruptScan, match="does not match the data"):
        load_scan(write_gsf(tmp_path / "t.gsf", h, GSF, extra=b"\0" * 4))
    p = write_gsf(tmp_path / "p.gsf", h, GSF)
    raw = bytearray(p.read_bytes())
    nul = raw.index(0)
    if (4 - nul % 4) > 1:
        raw[nul + 1] = ord("x")
        p.write_bytes(bytes(raw))
        with pytest.raises(CorruptScan, match="padding"):
            load_scan(p)


@pytest.mark.parametrize("edit, error, needle", [
    ({"XReal": "1e306"}, CorruptScan, "outside any AFM"),
    ({"XReal": "0"}, CorruptScan, "positive length"),
    ({"XReal": "nan"}, CorruptScan, "positive length"),
    ({"YReal": None}, MissingCalibration, "YReal"),
])
def test_gsf_absurd_or_missing_sizes_are_refused(tmp_path, rng, edit, error, needle):
    header = {**GSF, **edit}
    header = {k: v for k, v in header.items() if v is not None}
    with pytest.raises(error, match=needle):
        load_scan(write_gsf(tmp_path / "s.gsf", rng.normal(size=(5, 6)) * 1e-9, header))


def test_heights_beyond_an_afm_z_travel_are_refused(tmp_path, rng):
    """A 16-bit count misread as metres (or a flipped float exponent) is no AFM height."""
    h = rng.normal(size=(5, 6)) * 1e-9
    h[2, 3] = 0.148
    with pytest.raises(CorruptScan, match="z travel"):
        load_scan(write_gsf(tmp_path / "z.gsf", h, GSF))


# ----------------------------------------------------------------------------- Park TIFF
def write_park(path, raw: np.ndarray, *, data_type=2, version=0x01000002, gain=1.0, zscale=1.0, zoff=0.0,
               z_unit="nm", image_type=0, size_um=(1.0, 1.0), header_bytes=580) -> Path:
    tifffile = pytest.importorskip("tifffile")
    ny, nx = raw.shape
    head = bytearray(header_bytes)
    struct.pack_into("<I", head, 0, image_type)
    head[4 : 4 + 20] = "Topography".encode("utf-16-le")
    struct.pack_into("<II", head, 100, nx, ny)
    struct.pack_into("<II", head, 128, 1, 1)
    struct.pack_into("<dd", head, 140, *size_um)
    struct.pack_into("<ddd", head, 220, gain, zscale, zoff)
    head[244 : 244 + 2 * len(z_unit)] = z_unit.encode("utf-16-le")
    if header_bytes >= 352:
        struct.pack_into("<I", head, 348, data_type)
    payload = np.ascontiguousarray(raw).tobytes()
    tifffile.imwrite(path, np.zeros((8, 8), np.uint8), extratags=[
        (50432, "I", 1, 0x0E031301, True), (50433, "I", 1, version, True),
        (50434, "B", len(payload), payload, True), (50435, "B", len(head), bytes(head), True)])
    return path


@pytest.mark.parametrize("data_type, dtype", [(0, "<i2"), (1, "<i4"), (2, "<f4")])
def test_park_data_types_and_scaling_follow_the_format(tmp_path, rng, data_type, dtype):
    """z = gain (raw z_scale + z_offset), for every data type of a version 2 header."""
    raw = rng.integers(-3000, 3000, size=(6, 8)).astype(dtype)
    p = write_park(tmp_path / "p.tiff", raw, data_type=data_type, gain=-0.5, zscale=2.0, zoff=5.0)
    scan = load_scan(p)
    assert scan.metadata["format"] == "park-tiff" and scan.metadata["data_type"] == np.dtype(dtype).name
    np.testing.assert_allclose(scan.heights, -0.5 * (raw.astype(np.float64) * 2.0 + 5.0) * 1e-9, rtol=1e-12)
    assert scan.dx == pytest.approx(1e-6 / 8) and scan.dy == pytest.approx(1e-6 / 6)


def test_park_version_1_is_int16_and_a_zero_z_scale_means_one(tmp_path, rng):
    raw = rng.integers(-3000, 3000, size=(6, 8)).astype("<i2")
    p = write_park(tmp_path / "v1.tiff", raw, version=0x01000001, header_bytes=356, gain=0.25, zscale=0.0)
    np.testing.assert_allclose(load_scan(p).heights, 0.25 * raw * 1e-9, rtol=1e-12)


@pytest.mark.parametrize("kwargs, needle", [
    ({"data_type": 0}, "need 96 bytes"),         # float32 bytes said to be int16: the misread of the issue
    ({"data_type": 7}, "data type is 7"),
    ({"gain": 0.0}, "data gain is 0.0"),
    ({"gain": float("nan")}, "data gain is nan"),
    ({"image_type": 2}, "not a 2-D image"),
    ({"zoff": float("inf")}, "z offset"),
])
def test_park_headers_that_contradict_the_data_are_refused(tmp_path, rng, kwargs, needle):
    raw = rng.normal(size=(6, 8)).astype("<f4")
    with pytest.raises(CorruptScan, match=needle):
        load_scan(write_park(tmp_path / "x.tiff", raw, **kwargs))


def test_park_width_edit_of_the_real_file_is_refused(tmp_path):
    """The real file's header says 256 x 256 float32; 512 x 256 would read its floats as int16
    (Gwyddion's old reader: +-0.15 m heights)."""
    data = bytearray(real_scan_path("Park_20210916_034.tiff").read_bytes())
    tifffile = pytest.importorskip("tifffile")
    with tifffile.TiffFile(real_scan_path("Park_20210916_034.tiff")) as tif:
        offset = tif.pages[0].tags[50435].valueoffset
    struct.pack_into("<I", data, offset + 100, 512)
    p = tmp_path / "wide.tiff"
    p.write_bytes(bytes(data))
    with pytest.raises(CorruptScan, match="512 x 256 float32"):
        load_scan(p)


# ---------------------------------------------------------------------------- other z scales
def test_a_zero_or_non_finite_z_scale_is_refused_by_every_reader(tmp_path, rng):
    from tests.support.scan_writers import write_nanoscope, write_nid, write_wsxm

    img = rng.integers(-2000, 2000, size=(8, 8))
    write_nid(tmp_path / "z.nid", [("Scan forward", "Z-Axis", img)], zrange=0.0)
    with pytest.raises(CorruptScan, match="Dim2Range is 0.0"):
        load_scan(tmp_path / "z.nid")
    write_wsxm(tmp_path / "z.top", img.astype("<i2"), kind="short", zamp="0 nm")
    with pytest.raises(CorruptScan, match="Z Amplitude is 0.0"):
        load_scan(tmp_path / "z.top")
    write_nanoscope(tmp_path / "z.spm", [img], sens_nm_per_v=0.0, names=("Height",), directions=("Trace",))
    with pytest.raises(CorruptScan, match="z scale"):
        load_scan(tmp_path / "z.spm")


# --------------------------------------------------------------------------------- NanoScope
def _edit_veeco(tmp_path, old: bytes, new: bytes) -> Path:
    data = real_scan_path("Veeco_20160622.003").read_bytes()
    assert old in data
    p = tmp_path / "v.003"
    p.write_bytes(data.replace(old, new, 1))
    return p


def test_nanoscope_data_blocks_must_sit_where_the_header_says(tmp_path):
    """A digit changed in a Data offset (40960 -> 40961) read every pixel one byte off, and bytes
    inserted into the text header shifted every block: both are refused now."""
    with pytest.raises(CorruptScan, match="overlap"):
        load_scan(_edit_veeco(tmp_path, b"\\Data offset: 40960", b"\\Data offset: 40961"))
    with pytest.raises(CorruptScan, match="after the 40960-byte header"):
        load_scan(_edit_veeco(tmp_path, b"\\Data offset: 40960", b"\\Data offset: 30960"))
    with pytest.raises(CorruptScan, match="does not match the data"):  # 9 bytes inserted into a value
        load_scan(_edit_veeco(tmp_path, b"\\Scan size: 1.76908", b"\\Scan size: 1.76908000000000"))
    with pytest.raises(CorruptScan, match="header size"):
        load_scan(_edit_veeco(tmp_path, b"\\Data length: 40960", b"\\Data length: 10960"))


# ----------------------------------------------------------------------------- Igor .ibw
def _fix_checksum(buf: bytearray) -> None:
    """Make the first 380 bytes sum to 0 again (TN003) by adjusting the checksum field at byte 2."""
    struct.pack_into("<h", buf, 2, 0)
    total = sum(struct.unpack("<190h", bytes(buf[:380]))) & 0xFFFF
    struct.pack_into("<H", buf, 2, (-total) & 0xFFFF)


def _hostile_ibw(tmp_path, field_offset: int, value: int) -> Path:
    buf = bytearray(real_scan_path("AR_20211011.ibw").read_bytes())
    struct.pack_into("<l", buf, field_offset, value)
    _fix_checksum(buf)
    p = tmp_path / f"h{field_offset}.ibw"
    p.write_bytes(bytes(buf))
    return p


@pytest.mark.parametrize("offset, value, needle", [
    (36 + 8, 0x7FFFFF00, "dimLabelsSize\\[2\\]"),   # the field that made igor2 allocate 8.7 GB
    (20, -5, "dimEUnitsSize\\[0\\] is -5"),
    (4, 999, "wfmSize gives"),
    (64 + 68, 129, "do not multiply"),            # nDim[0]
    (64 + 12, 10, "do not multiply"),             # npnts
])
def test_igor_header_is_checked_before_igor2_reads_it(tmp_path, offset, value, needle):
    p = _hostile_ibw(tmp_path, offset, value)
    tracemalloc.start()
    try:
        with pytest.raises(CorruptScan, match=needle):
            load_scan(p)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 8 * p.stat().st_size + (4 << 20)


def test_igor_checksum_and_version_are_checked(tmp_path):
    buf = bytearray(real_scan_path("AR_20211011.ibw").read_bytes())
    buf[200] ^= 0x10  # a bit of the wave header, checksum left as is
    (tmp_path / "c.ibw").write_bytes(bytes(buf))
    with pytest.raises(CorruptScan, match="checksum"):
        load_scan(tmp_path / "c.ibw")
    v2 = bytearray(142)
    struct.pack_into("<h", v2, 0, 2)
    struct.pack_into("<H", v2, 14, (-sum(struct.unpack("<71h", bytes(v2)))) & 0xFFFF)
    (tmp_path / "v2.ibw").write_bytes(bytes(v2))
    with pytest.raises(CorruptScan, match="version 2 holds a one-dimensional wave"):
        load_scan(tmp_path / "v2.ibw")


def test_a_failed_igor2_read_cannot_poison_the_next_one(tmp_path):
    """igor2's shared thread-local parser keeps the state of a read that failed on a huge
    dimLabelsSize, and then fails every later read in the process. arsurf refuses that file
    before igor2 sees it and reads with a parser of its own, so a real file still reads after
    the shared parser has been broken (shown in a child process under a 2 GiB address-space limit)."""
    pytest.importorskip("igor2")
    hostile = _hostile_ibw(tmp_path, 36 + 8, 0x7FFFFF00)
    real = real_scan_path("AR_20211011.ibw")
    code = textwrap.dedent(f"""
        import resource
        resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))
        import igor2.binarywave as bw
        from arsurf.errors import CorruptScan
        from arsurf.scan.io import load_scan
        try:
            load_scan({str(hostile)!r})
        except CorruptScan as exc:
            print("refused:", "dimLabelsSize" in str(exc))
        try:
            bw.load({str(hostile)!r})  # igor2 alone: it runs out of memory and keeps the state
        except MemoryError:
            print("igor2 failed")
        try:
            bw.load({str(real)!r})
            print("shared parser fine")
        except Exception:
            print("shared parser poisoned")
        print("arsurf reads", load_scan({str(real)!r}).shape)
    """)
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT,
                         env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    out = run.stdout
    assert "refused: True" in out and "arsurf reads (128, 128)" in out, (out, run.stderr[-2000:])
    assert "igor2 failed" in out  # the peer: what happened before


# --------------------------------------------------------------- non-height channels (any reader)
def test_a_length_channel_named_as_another_quantity_is_fitted_only_on_request():
    amp = load_scan(real_scan_path("AR_20211011.ibw"), "AmplitudeRetrace")
    assert amp.metadata["z_unit"] == "m" and amp.metadata["height"] is False
    with pytest.raises(InvalidHeights, match="as_height"):
        arsurf.fit_surface(amp)
    marked = amp.as_height()
    assert marked.metadata["height"] is True and marked.history[-1]["operation"] == "as_height"
    small = Scan(marked.heights[:12, :12], dx=marked.dx, dy=marked.dy, metadata=marked.metadata)
    assert arsurf.fit_surface(small).shape == (14, 14)
    for name in ("HeightRetrace", "ZSensorRetrace"):
        assert load_scan(real_scan_path("AR_20211011.ibw"), name).metadata["height"] is True


def test_every_real_default_channel_is_a_height():
    names = ["2024-10-24_104052_PH_wg_wv_No3_15slits_pol45deg_anal90deg_fine.gwy",
             "2018-02-09_1506_PH_dt20nmwindow1_Z_C.gsf", "STM_nanonis_generic_4_5.sxm", "AR_20211011.ibw",
             "sample_0.jpk", "Veeco_20160622.003", "Park_20210916_034.tiff", "sample_0.h5-jpk",
             "sample_0_1.topostats"]
    for name in names:
        scan = load_scan(real_scan_path(name))
        assert scan.metadata["z_unit"] == "m" and scan.metadata["height"] is True, (name, scan.channel)


# ------------------------------------------------------------------- §2: names users can type
def test_an_igor_label_with_old_text_after_its_nul_is_listed_and_selected_cut(tmp_path, capsys):
    """The real file with 'race' left after PhaseRetrace's NUL (what the issue's file had)."""
    data = bytearray(real_scan_path("AR_20211011.ibw").read_bytes())
    i = data.index(b"PhaseRetrace\0")
    data[i + 13 : i + 17] = b"race"  # dimension labels lie outside the checksummed header
    p = tmp_path / "nul.ibw"
    p.write_bytes(bytes(data))
    scan = load_scan(p, "PhaseRetrace")
    assert scan.metadata["channels"] == ["HeightRetrace", "AmplitudeRetrace", "PhaseRetrace", "ZSensorRetrace"]
    assert scan.metadata["z_unit"] == "deg" and scan.channel == "PhaseRetrace"
    from arsurf.cli import main

    assert main(["info", str(p), "--channel", "PhaseRetrace"]) == 0
    assert "PhaseRetracerace" not in capsys.readouterr().out


def test_two_jpk_channels_of_one_name_are_both_selectable(tmp_path):
    """A JPK file with two 'measuredHeight (trace)' pages (as JPK QI images have): the second is
    'measuredHeight (trace) #2', each name gives its own page, and ChannelNotFound lists both."""
    src = real_scan_path("sample_0.jpk")
    data = src.read_bytes()
    hits = [m.start() for m in re.finditer(rb"retrace : true", data)]
    page = 1  # the properties of page 2, the measuredHeight retrace channel
    edited = data[: hits[page]] + b"retrace : nope" + data[hits[page] + 14 :]
    p = tmp_path / "qi.jpk"
    p.write_bytes(edited)
    first = load_scan(p, "measuredHeight (trace)")
    second = load_scan(p, "measuredHeight (trace) #2")
    names = first.metadata["channels"]
    assert names.count("measuredHeight (trace)") == 1 and "measuredHeight (trace) #2" in names
    np.testing.assert_array_equal(first.heights, load_scan(src, "measuredHeight (retrace)").heights)
    np.testing.assert_array_equal(second.heights, load_scan(src, "measuredHeight (trace)").heights)
    with pytest.raises(ChannelNotFound, match=r"measuredHeight \(trace\) #2"):
        load_scan(p, "nosuch")
