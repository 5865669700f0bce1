"""The arsurf command: info, fit, synth, export, the UDP pose source of `arsurf view`."""
import json
import socket
import time

import numpy as np
import pytest

from arsurf.cli import main
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


def test_bridge_loop_feels_the_surface_through_udp():
    """`arsurf view --bridge-port`'s loop: a client on loopback sends stylus poses, the 1 kHz loop
    moves the tip into the surface and sends back a force pushing the stylus up."""
    from arsurf.assembly import PRESETS, make_model
    from arsurf.haptics.client import HapticClient
    from arsurf.spline.surface import BSplineSurface
    from arsurf.live import bridge_loop
    from arsurf_viewer.live import live_scene

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    s = BSplineSurface.from_heights(np.zeros((60, 60)), (0.0, 57 * 4e-9), (0.0, 57 * 4e-9))
    key = bytes(range(32))
    p = PRESETS["viewer"]
    model = make_model(s, tip_radius=20e-9, effective_modulus=p.effective_modulus, work_of_adhesion=p.work_of_adhesion)
    live = bridge_loop(model, port=port, key=key).start()   # tip starts 2.5 R above the middle
    client = HapticClient(port=port, key=key)
    try:
        deadline = time.monotonic() + 15.0                 # generous: CI machines are shared
        z = 0.0
        while time.monotonic() < deadline:
            z = max(z - 1e-5, -3.3e-3)                     # lower the stylus 3.3 mm (5 mm/s) -> the tip 33 nm
            client.send_pose((0.0, 0.0, z))
            time.sleep(0.002)
            if client.poll()[2] > 1e-4 and z <= -3.3e-3:
                break
        force = client.poll()
        scene = live_scene(live, np.zeros(3), 1 / 30)
    finally:
        client.close()
        stats = live.stop()
    assert scene.depth > 0 and scene.force[2] > 0        # the tip is in the surface, pushed back
    assert force[2] > 1e-4 and abs(force[2]) <= 7.9      # the hand feels it, within the device limit
    assert stats.ticks > 100


def test_demo_without_an_opengl_context_fails_before_the_session_saying_what_to_install(tmp_path, monkeypatch, capsys):
    """Views asked for (the default) and no backend: exit 2, one line naming the packages, nothing run."""
    pytest.importorskip("pyvista")
    import arsurf_viewer

    from arsurf.errors import RENDERING_HINT, RenderingUnavailable

    def none():
        raise RenderingUnavailable(f"no OpenGL context can be made: no display, no EGL, no OSMesa; {RENDERING_HINT}")

    monkeypatch.setattr(arsurf_viewer, "choose_backend", none, raising=False)
    assert main(["demo", "--out", str(tmp_path / "demo")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("arsurf demo: error: no OpenGL") and "libosmesa6" in err[0]
    assert not (tmp_path / "demo").exists()
