"""The arsurf command: info, fit, synth, export, the UDP pose source of `arsurf view`."""
import json
import socket
import struct
import time
import zlib

import numpy as np
import pytest

from arsurf.cli import bridge_pose_source, main
from arsurf.spline.storage import load_surface
from conftest import real_scan_path


def test_info_reports_the_real_figures(capsys):
    assert main(["info", str(real_scan_path("Veeco_20160622.003")), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["format"] == "nanoscope" and info["pixels"] == "512 x 512"
    assert info["z_range_nm"] == pytest.approx(159.5, abs=0.05)


def test_fit_writes_a_surface_that_interpolates(tmp_path, capsys):
    out = tmp_path / "s.npz"
    assert main(["fit", str(real_scan_path("AR_20211011.ibw")), "-o", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["rms_residual_nm"] < 1e-6 and load_surface(out).shape == (130, 130)


def test_synth_then_export_round_trip(tmp_path, capsys):
    assert main(["synth", "--out", str(tmp_path / "scans")]) == 0
    assert main(["fit", str(tmp_path / "scans" / "sinusoid.npz"), "-o", str(tmp_path / "s.npz")]) == 0
    assert main(["export", str(tmp_path / "s.npz"), "-o", str(tmp_path / "s.stl"), "--solid"]) == 0
    import trimesh

    mesh = trimesh.load(tmp_path / "s.stl")
    assert mesh.is_watertight


def test_errors_are_one_line_messages(tmp_path, capsys):
    assert main(["info", str(tmp_path / "missing.gwy")]) == 2
    err = capsys.readouterr().err
    assert "arsurf info: error:" in err and "missing.gwy" in err


def test_bridge_pose_source_maps_stylus_motion_to_the_tip():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    start = np.array([1e-7, 2e-7, 3e-8])
    pose = bridge_pose_source(port, 1e-5, start)
    try:
        assert pose() is None  # nothing received yet
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as c:
            for seq, x in enumerate((0.0, 2e-3)):
                body = struct.pack("<4sBBHId3d3d4dI", b"ARSH", 1, 1, 0, seq + 1, time.monotonic() + seq,
                                   x, 0.0, 0.0, np.nan, np.nan, np.nan, 1.0, 0.0, 0.0, 0.0, 0)
                c.sendto(body + struct.pack("<I", zlib.crc32(body)), ("127.0.0.1", port))
                deadline = time.monotonic() + 2.0
                p = None
                while time.monotonic() < deadline:
                    p = pose()
                    if p is not None and (seq == 0 or p[0] > start[0]):
                        break
                    time.sleep(0.01)
        np.testing.assert_allclose(p, start + [2e-8, 0, 0], atol=1e-15)
    finally:
        pose.device.close()
