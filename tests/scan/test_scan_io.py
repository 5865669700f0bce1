"""load_scan/save_scan: synthetic files of every format without a real sample, round trips,
detection and the errors a user can act on.

The synthetic files are written here by small writers that follow each format's layout; the
tests check that the reader gives back what was written, in the project orientation
(row 0 = bottom of the image).
"""
from __future__ import annotations

import json
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from arsurf.errors import (
    ChannelNotFound,
    CorruptScan,
    InvalidHeights,
    ScanError,
    ScanFileNotFound,
    UnknownFormat,
)
from arsurf.scan.io import MissingCalibration, detect_format, load_scan, save_scan
from arsurf.scan.readers._common import parse_unit
from arsurf.scan.scan import Scan
from tests.support.scan_writers import write_nanoscope, write_nid, write_wsxm


def image(ny, nx, rng):
    """A test image whose rows differ (a ramp in y plus noise): a flip cannot go unnoticed."""
    return np.add.outer(np.arange(ny) * 1.0, np.zeros(nx)) + rng.normal(0, 0.1, (ny, nx))


# ------------------------------------------------------------------------ NanoScope (binary)
def test_nanoscope_synthetic_z_scale_orientation_and_channels(tmp_path, rng):
    ny, nx = 12, 16
    raw_h = rng.integers(-30000, 30000, (ny, nx))
    raw_a = rng.integers(-30000, 30000, (ny, nx))
    p = tmp_path / "synthetic.001"
    write_nanoscope(p, [raw_h, raw_a])
    s = load_scan(p)
    assert s.channel == "Height (Trace)" and s.metadata["channels"] == ["Height (Trace)", "Amplitude (Retrace)"]
    # z = raw / 2**16 * hard value * sensitivity, first stored line = row 0 (bottom)
    np.testing.assert_allclose(s.heights, raw_h / 65536 * 41.60368 * 7e-9, rtol=1e-12)
    assert s.dx == pytest.approx(1.5e-6 / nx) and s.dy == pytest.approx(1.5e-6 / ny)
    a = load_scan(p, "Amplitude")
    np.testing.assert_allclose(a.heights, raw_a / 65536 * 2.5, rtol=1e-12)
    assert a.metadata["z_unit"] == "V"


def test_nanoscope_32bit_and_non_square(tmp_path, rng):
    raw = rng.integers(-2**30, 2**30, (6, 10))
    p = tmp_path / "wide.spm"
    write_nanoscope(p, [raw], bpp=4, names=("Height",), directions=("Retrace",), size_um=2.0)
    s = load_scan(p)
    np.testing.assert_allclose(s.heights, raw / 2.0**32 * 41.60368 * 7e-9, rtol=1e-12)
    assert s.dx == pytest.approx(2e-6 / 10) and s.dy == pytest.approx(2e-6 / 6)


# --------------------------------------------------------------------------------- WSxM
def test_wsxm_double_is_in_z_amplitude_unit_and_top_row_first(tmp_path, rng):
    data = image(8, 11, rng)
    p = tmp_path / "a.top"
    write_wsxm(p, data)
    s = load_scan(p)
    assert s.metadata["format"] == "wsxm" and s.channel == "Topography"
    np.testing.assert_allclose(s.heights, data[::-1] * 1e-9, rtol=1e-15)  # first stored row is the top
    assert s.dx == pytest.approx(2e-6 / 11) and s.dy == pytest.approx(1e-6 / 8)


def test_wsxm_short_spans_z_amplitude(tmp_path, rng):
    data = rng.integers(-2000, 3000, (5, 7))
    p = tmp_path / "b.stp"
    write_wsxm(p, data, kind="short", zamp="40 nm")
    s = load_scan(p)
    assert (s.heights.max() - s.heights.min()) == pytest.approx(40e-9, rel=1e-12)
    np.testing.assert_allclose(s.heights, data[::-1] * 40e-9 / (data.max() - data.min()), rtol=1e-12)


# --------------------------------------------------------------------------- Nanosurf .nid
def test_nid_scaling_and_channels(tmp_path, rng):
    fwd = rng.integers(-32768, 32767, (6, 9))
    bwd = rng.integers(-32768, 32767, (6, 9))
    amp = rng.integers(-32768, 32767, (6, 9))
    p = tmp_path / "x.nid"
    write_nid(p, [("Scan forward", "Z-Axis", fwd), ("Scan forward", "Amplitude", amp),
                  ("Scan backward", "Z-Axis", bwd)])
    s = load_scan(p)
    assert s.channel == "Z-Axis (Scan forward)"
    np.testing.assert_allclose(s.heights, -1e-6 + 2e-6 * (fwd + 32768) / 65536, rtol=1e-12)
    assert s.dx == pytest.approx(5e-6 / 9) and s.dy == pytest.approx(4e-6 / 6)
    b = load_scan(p, "Z-Axis (Scan backward)")
    np.testing.assert_allclose(b.heights, -1e-6 + 2e-6 * (bwd + 32768) / 65536, rtol=1e-12)
    with pytest.raises(ChannelNotFound, match="ambiguous"):
        load_scan(p, "Z-Axis")


# --------------------------------------------------------------------------- ASCII and XYZ
def test_ascii_matrix_gwyddion_header(tmp_path, rng):
    data = image(5, 7, rng) * 1e-9
    p = tmp_path / "m.txt"
    lines = ["# Channel: Z raw", "# Width: 700.000 nm", "# Height: 0.5 \u00b5m", "# Value units: m"]
    lines += ["\t".join(repr(float(v)) for v in row) for row in data]
    p.write_text("\n".join(lines) + "\n", encoding="utf-8")
    s = load_scan(p)
    assert s.metadata["format"] == "ascii-matrix" and s.channel == "Z raw"
    np.testing.assert_array_equal(s.heights, data[::-1])  # first line is the top row
    assert s.dx == pytest.approx(100e-9) and s.dy == pytest.approx(100e-9)


def test_bare_ascii_matrix_needs_calibration(tmp_path, rng):
    data = image(4, 3, rng)
    p = tmp_path / "bare.asc"
    p.write_text("\n".join(", ".join(f"{v:.6f}" for v in row) for row in data))
    with pytest.raises(MissingCalibration, match=r"pass its pixel spacing"):
        load_scan(p)
    with pytest.raises(MissingCalibration, match=r"z_unit='nm'"):
        load_scan(p, dx=1e-8, dy=2e-8)
    s = load_scan(p, dx=1e-8, dy=2e-8, z_unit="nm")
    np.testing.assert_allclose(s.heights, np.round(data, 6)[::-1] * 1e-9, rtol=1e-12)


def test_xyz_grid_any_order_with_missing_point(tmp_path, rng):
    ny, nx = 4, 5
    z = image(ny, nx, rng) * 1e-9
    pts = [(ix * 20e-9, 1e-6 + iy * 30e-9, float(z[iy, ix])) for iy in range(ny) for ix in range(nx)]
    order = rng.permutation(len(pts))
    missing = order[-1]
    p = tmp_path / "pts.xyz"
    p.write_text("\n".join(f"{pts[i][0]!r} {pts[i][1]!r} {pts[i][2]!r}" for i in order[:-1]))
    s = load_scan(p)
    assert s.metadata["format"] == "xyz" and s.metadata["nan_count"] == 1
    want = z.copy()
    want.flat[missing] = np.nan
    np.testing.assert_array_equal(s.heights, want)
    assert s.dx == pytest.approx(20e-9) and s.dy == pytest.approx(30e-9)
    assert s.metadata["y0"] == pytest.approx(1e-6)


def test_xyz_scattered_points_are_refused(tmp_path, rng):
    p = tmp_path / "scatter.xyz"
    xy = rng.uniform(0, 1e-6, (50, 2))
    p.write_text("\n".join(f"{float(x)!r} {float(y)!r} 0.0" for x, y in xy))
    with pytest.raises(CorruptScan, match="not on a regular grid"):
        load_scan(p)


# ------------------------------------------------------------------------------ round trips
finite = st.floats(-1e-5, 1e-5, allow_nan=False, allow_infinity=False, width=64)
spacing = st.floats(1e-11, 1e-5, allow_nan=False, allow_infinity=False)


@st.composite
def scans(draw):
    ny = draw(st.integers(1, 9))
    nx = draw(st.integers(1, 9))
    h = np.array(draw(st.lists(finite, min_size=ny * nx, max_size=ny * nx))).reshape(ny, nx)
    nan = draw(st.lists(st.booleans(), min_size=ny * nx, max_size=ny * nx))
    h[np.array(nan).reshape(ny, nx) & (np.arange(ny * nx).reshape(ny, nx) > 0)] = np.nan
    meta = {"history": [{"step": "level", "order": draw(st.integers(0, 3))}], "note": draw(st.text(max_size=20))}
    return Scan(h, dx=draw(spacing), dy=draw(spacing), channel=draw(st.sampled_from(["Height", "Z raw", "µ=x"])),
                metadata=meta, source="synthetic:hypothesis")


HYP = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@HYP
@given(scan=scans())
def test_npz_round_trip_is_bit_exact(tmp_path, scan):
    p = tmp_path / "r.npz"
    save_scan(scan, p)
    back = load_scan(p)
    assert back.heights.tobytes() == scan.heights.tobytes()  # NaN payloads included
    assert (back.dx, back.dy, back.channel) == (scan.dx, scan.dy, scan.channel)
    assert {k: v for k, v in back.metadata.items() if k not in ("format", "nan_count")} == json.loads(
        json.dumps({k: v for k, v in scan.metadata.items() if k not in ("format", "nan_count")}))
    assert back.metadata["format"] == "npz" and back.metadata["nan_count"] == scan.nan_count


@HYP
@given(scan=scans())
def test_npy_round_trip_is_bit_exact(tmp_path, scan):
    p = tmp_path / "r.npy"
    save_scan(scan, p)
    back = load_scan(p)
    assert back.heights.tobytes() == scan.heights.tobytes()
    assert (back.dx, back.dy, back.channel) == (scan.dx, scan.dy, scan.channel)
    assert back.metadata["history"] == scan.metadata["history"]


@HYP
@given(scan=scans())
def test_npy_sidecar_names_the_unit_and_an_older_one_still_reads(tmp_path, scan):
    p = tmp_path / "r.npy"
    save_scan(scan, p)
    side = tmp_path / "r.npy.json"
    info = json.loads(side.read_text(encoding="utf-8"))
    assert (info["dx_m"], info["dy_m"]) == (scan.dx, scan.dy) and "dx" not in info  # arsurf.units: unit in the key
    info["dx"], info["dy"] = info.pop("dx_m"), info.pop("dy_m")  # as written before the rule
    side.write_text(json.dumps(info), encoding="utf-8")
    back = load_scan(p)
    assert (back.dx, back.dy) == (scan.dx, scan.dy) and back.heights.tobytes() == scan.heights.tobytes()


@HYP
@given(scan=scans())
def test_gsf_round_trip_exact_to_float32(tmp_path, scan):
    p = tmp_path / "r.gsf"
    save_scan(scan, p)
    back = load_scan(p)
    np.testing.assert_array_equal(back.heights, scan.heights.astype(np.float32).astype(np.float64))
    assert (back.dx, back.dy) == (scan.dx, scan.dy)  # spacings exact (Arsurf_dx/dy keys)
    assert back.channel == scan.channel


def test_gsf_written_is_read_by_gsffile_top_row_first(tmp_path, rng):
    gsffile = pytest.importorskip("gsffile")
    s = Scan(image(6, 4, rng) * 1e-9, dx=1e-8, dy=3e-8, channel="Z")
    p = tmp_path / "g.gsf"
    save_scan(s, p)
    data, meta = gsffile.read_gsf(p)
    np.testing.assert_array_equal(data, s.heights[::-1].astype(np.float32))
    assert meta["XReal"] == pytest.approx(4e-8) and meta["YReal"] == pytest.approx(18e-8)
    assert meta["ZUnits"] == "m"


def test_gsf_value_with_equals_sign(tmp_path, rng):
    # valid per the spec (split at the first '='); gsffile 0.5.5 rejects it
    s = Scan(image(3, 3, rng) * 1e-9, dx=1e-9, dy=1e-9, channel="a=b")
    p = tmp_path / "eq.gsf"
    save_scan(s, p)
    assert load_scan(p).channel == "a=b"


def test_generic_npz_and_npy_without_calibration(tmp_path, rng):
    a = image(3, 4, rng)
    p = tmp_path / "plain.npz"
    np.savez(p, topo=a, phase=a * 2, dx=np.array(1e-8), dy=np.array(2e-8))
    with pytest.raises(MissingCalibration, match="z_unit"):
        load_scan(p)
    s = load_scan(p, z_unit="nm")
    assert s.channel == "topo" and s.metadata["channels"] == ["topo", "phase"]
    np.testing.assert_allclose(s.heights, a * 1e-9)
    assert (s.dx, s.dy) == (1e-8, 2e-8)
    q = tmp_path / "plain.npy"
    np.save(q, a)
    with pytest.raises(MissingCalibration, match="bare array"):
        load_scan(q)
    assert load_scan(q, dx=1e-9, dy=1e-9, z_unit="nm").heights.shape == (3, 4)


# --------------------------------------------------------------------------------- errors
def test_missing_file(tmp_path):
    with pytest.raises(ScanFileNotFound, match=r"nope\.gwy.*does not exist"):
        load_scan(tmp_path / "nope.gwy")
    with pytest.raises(ScanFileNotFound, match="not a file"):
        load_scan(tmp_path)


def test_unknown_format(tmp_path):
    p = tmp_path / "photo.jpg"
    p.write_bytes(b"\xff\xd8\xff\xe0JFIF" + bytes(100))
    with pytest.raises(UnknownFormat, match=r"photo\.jpg.*supported: npy"):
        load_scan(p)
    with pytest.raises(UnknownFormat, match=r"\.png"):
        save_scan(Scan(np.zeros((2, 2)), dx=1e-9, dy=1e-9), tmp_path / "x.png")


def test_truncated_and_corrupt_files_name_the_problem(tmp_path, rng):
    s = Scan(image(8, 8, rng) * 1e-9, dx=1e-9, dy=1e-9)
    p = tmp_path / "t.gsf"
    save_scan(s, p)
    p.write_bytes(p.read_bytes()[:-10])
    with pytest.raises(CorruptScan, match=r"t\.gsf.*truncated"):
        load_scan(p)
    q = tmp_path / "t.001"
    write_nanoscope(q, [rng.integers(-100, 100, (4, 4))], names=("Height",), directions=("Trace",))
    q.write_bytes(q.read_bytes().replace(b"Samps/line: 4\r\n\\Number", b"Samps/line: x\r\n\\Number"))
    with pytest.raises(CorruptScan, match="Samps/line is not an integer"):
        load_scan(q)


def test_all_nan_channel(tmp_path):
    p = tmp_path / "nan.npz"
    save_scan(Scan(np.full((3, 3), np.nan), dx=1e-9, dy=1e-9), p)
    with pytest.raises(InvalidHeights, match="no finite pixel"):
        load_scan(p)


def test_calibration_options_rejected_where_the_file_has_its_own(tmp_path, rng):
    p = tmp_path / "c.gsf"
    save_scan(Scan(image(3, 3, rng), dx=1e-9, dy=1e-9), p)
    with pytest.raises(ScanError, match="states its own calibration"):
        load_scan(p, dx=1e-9)


def test_detect_format_by_extension_when_content_is_silent(tmp_path):
    p = tmp_path / "empty.gwy"
    p.write_bytes(b"")
    assert detect_format(p) == "gwy"
    with pytest.raises(CorruptScan, match="GWYP"):
        load_scan(p)


def test_inf_pixels_become_nan(tmp_path, rng):
    h = image(4, 4, rng).astype(np.float32)
    p = tmp_path / "inf.gsf"
    save_scan(Scan(h * 1e-9, dx=1e-9, dy=1e-9), p)
    raw = bytearray(p.read_bytes())
    raw[-4:] = struct.pack("<f", np.inf)
    p.write_bytes(bytes(raw))
    s = load_scan(p)
    assert s.metadata["inf_count"] == 1 and s.metadata["nan_count"] == 1 and np.isnan(s.heights[0, -1])


@pytest.mark.parametrize("unit, factor, base", [("nm", 1e-9, "m"), ("~m", 1e-6, "m"), ("\u00b5m", 1e-6, "m"),
                                                ("\u00c5", 1e-10, "m"), ("mV", 1e-3, "V"), ("pA", 1e-12, "A"),
                                                ("m", 1.0, "m"), ("deg", 1.0, "deg")])
def test_parse_unit(unit, factor, base):
    f, b = parse_unit(unit)
    assert b == base and f == pytest.approx(factor, rel=1e-15)


def test_channel_names_are_unique_and_each_selectable():
    """Two channels of one name (JPK QI: measuredHeight twice) get '#2': both reachable."""
    from arsurf.errors import ChannelNotFound
    from arsurf.scan.readers._common import Channel, select_channel

    chans = [Channel("measuredHeight (trace)", key=1, unit="m", direction="forward"),
             Channel("measuredHeight (trace)", key=2, unit="m", direction="forward")]
    assert select_channel("f", chans, "measuredHeight (trace) #2").key == 2
    assert select_channel("f", chans, "measuredHeight (trace)").key == 1
    with pytest.raises(ChannelNotFound, match=r"#2"):
        select_channel("f", chans, "height")


def test_igor_labels_are_cut_at_the_first_nul():
    import numpy as np

    from arsurf.scan.readers.ibw import _text

    assert _text(b"PhaseRetrace\x00race") == "PhaseRetrace"
    assert _text(np.frombuffer(b"HeightTrace\x00\x00ce", dtype="S1")) == "HeightTrace"


def test_a_gwyddion_1_file_is_refused_plainly(tmp_path):
    from arsurf.errors import ScanError

    p = tmp_path / "old.gwy"
    p.write_bytes(b"GWYOGwyContainer\x00" + b"\x00" * 64)
    with pytest.raises(ScanError, match="Gwyddion 1.x file"):
        load_scan(p)


def test_implausible_calibrations_are_refused_not_fitted(tmp_path, rng):
    """A header that makes pixels 1e306 m, the z scale zero, or heights a tenth of a metre is a
    misread, not an AFM scan; a non-height channel is never fitted as a height."""
    import arsurf
    from arsurf.errors import InvalidHeights, ScanError

    a = image(6, 6, rng)
    p = tmp_path / "plain.npy"
    np.save(p, a)
    with pytest.raises(ScanError, match="pixel spacing is 1e\\+306 m"):
        load_scan(p, dx=1e306, dy=1e-9, z_unit="nm")
    with pytest.raises(ScanError, match="more than any AFM's z travel"):
        load_scan(p, dx=1e-9, dy=1e-9, z_unit="m")  # values ~1 'm': a 16-bit misread
    volts = load_scan(p, dx=1e-9, dy=1e-9, z_unit="V")
    assert volts.metadata["z_unit"] == "V"
    with pytest.raises(InvalidHeights, match="not heights"):
        arsurf.fit_surface(volts)


def test_gwy_writer_round_trips_and_gwyfile_reads_it(tmp_path, rng):
    """save_scan to .gwy: our reader gives back the heights, spacings, channel and missing pixels
    exactly; the reference reader gwyfile sees the same field and units."""
    import numpy as np

    gwyfile = pytest.importorskip("gwyfile")
    h = image(6, 9, rng) * 1e-9
    h[2, 3] = np.nan
    scan = Scan(h, dx=2e-9, dy=3e-9, channel="Topo")
    p = tmp_path / "out.gwy"
    save_scan(scan, p)
    back = load_scan(p)
    assert back.channel == "Topo" and back.shape == (6, 9)
    assert back.dx == pytest.approx(2e-9, rel=1e-15) and back.dy == pytest.approx(3e-9, rel=1e-15)
    np.testing.assert_array_equal(np.isnan(back.heights), np.isnan(h))
    np.testing.assert_array_equal(back.heights[~np.isnan(h)], h[~np.isnan(h)])
    field = gwyfile.util.get_datafields(gwyfile.load(str(p)))["Topo"]
    assert field.data.shape == (6, 9) and field.xreal == pytest.approx(9 * 2e-9)
    assert field.si_unit_z.unitstr == "m"
    np.testing.assert_array_equal(field.data[::-1][~np.isnan(h)], h[~np.isnan(h)])  # Gwyddion: row 0 on top
