"""The CLI never leaks a traceback and never silently accepts nonsense (issue #14 §4): every
error is one line on stderr naming the flag or file, with exit status 2."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from tests.support.real_scans import real_scan_path

from arsurf import __version__
from arsurf.cli import main

ROOT = Path(__file__).resolve().parents[2]
SCAN = ROOT / "scans" / "sinusoid.npz"


def _one_line_error(capsys, argv, *needles):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in err, err


@pytest.mark.parametrize("value", ["-3", "nan", "inf", "abc"])
def test_a_bad_smoothing_width_is_refused(capsys, value, tmp_path):
    _one_line_error(capsys, ["fit", str(SCAN), "-o", str(tmp_path / "s.npz"), "--sigma-nm", value], "--sigma-nm")


def test_a_missing_output_folder_is_one_line(capsys, tmp_path):
    code = main(["fit", str(SCAN), "-o", str(tmp_path / "no" / "such" / "dir" / "x.npz")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "Traceback" not in err and "no/such/dir" in err, err


def test_exporting_a_scan_says_to_fit_it_first(capsys, tmp_path):
    code = main(["export", str(real_scan_path("sample_0.jpk")), "-o", str(tmp_path / "x.stl")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "arsurf fit" in err, err


def test_version_and_python_dash_m():
    run = subprocess.run([sys.executable, "-m", "arsurf", "--version"], capture_output=True, text=True,
                         timeout=120, cwd=ROOT)
    assert run.returncode == 0 and run.stdout.strip() == f"arsurf {__version__}"


def test_help_has_no_rst_markup():
    run = subprocess.run([sys.executable, "-m", "arsurf", "--help"], capture_output=True, text=True,
                         timeout=120, cwd=ROOT)
    assert run.returncode == 0 and "``" not in run.stdout


def test_a_closed_pipe_is_not_a_traceback():
    cmd = f"{sys.executable} -m arsurf info {real_scan_path('Veeco_20160622.003')} | head -c 1"
    run = subprocess.run(cmd, shell=True, capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert "Traceback" not in run.stderr and "BrokenPipe" not in run.stderr, run.stderr


def test_level_choices_are_the_methods_and_the_help_shows_the_default(capsys):
    from arsurf.scan.level import METHODS

    _one_line_error(capsys, ["fit", str(SCAN), "-o", "x.npz", "--level", "planar"], "--level", "rows-median")
    with pytest.raises(SystemExit):
        main(["fit", "--help"])
    out = capsys.readouterr().out
    assert all(m in out for m in METHODS) and "default: plane" in out


def test_the_control_shape_message_states_the_rule_that_is_applied(capsys, tmp_path):
    """(nx+2, ny+2) interpolates, (4..nx, 4..ny) approximates: 257 is refused with that rule."""
    from arsurf.scan.io import load_scan

    nx = load_scan(SCAN).shape[1]
    assert main(["fit", str(SCAN), "-o", str(tmp_path / "s.npz"), "--control", str(nx + 1), str(nx + 1)]) == 2
    err = capsys.readouterr().err
    assert f"({nx + 2}, {nx + 2}) to interpolate" in err and f"({nx}, {nx}) to approximate" in err


def test_info_reports_a_non_height_channel_in_its_own_unit(capsys):
    import json

    assert main(["info", str(real_scan_path("sample_0.spm")), "--channel", "Adhesion", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert "z_min_nm" not in info and "z_min_V" in info and info["units"]["reported"] == "V"
    assert main(["info", str(real_scan_path("sample_0.spm")), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["z_min_nm"] == pytest.approx(132.126, abs=1e-3)
    assert info["scan_size_nm"][0] == pytest.approx(505.859, abs=1e-3)
    assert info["first_to_last_pixel_nm"][0] == pytest.approx(505.859 * 1023 / 1024, abs=1e-3)


def test_a_bare_matrix_needs_and_takes_its_calibration_from_flags(capsys, tmp_path):
    import json

    import numpy as np

    path = tmp_path / "bare.txt"
    np.savetxt(path, np.arange(30.0).reshape(5, 6))
    assert main(["info", str(path)]) == 2
    err = capsys.readouterr().err
    assert "--dx-nm" in err and len(err.strip().splitlines()) == 1
    assert main(["info", str(path), "--dx-nm", "10", "--dy-nm", "20", "--z-unit", "nm", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["pixel_size_nm"] == pytest.approx([10.0, 20.0]) and info["z_max_nm"] == pytest.approx(29.0)


def test_convert_and_export_reach_gwyddion(tmp_path, capsys):
    """arsurf convert SCAN -o X.gwy writes the scan; arsurf export SURFACE -o X.gwy samples the
    (fitted) surface back on its pixels: both read back equal to the source."""
    import numpy as np

    from arsurf.scan.io import load_scan

    src = load_scan(SCAN)
    assert main(["convert", str(SCAN), "-o", str(tmp_path / "c.gwy")]) == 0
    conv = load_scan(tmp_path / "c.gwy")
    np.testing.assert_array_equal(conv.heights, src.heights)
    assert conv.dx == pytest.approx(src.dx, rel=1e-15)
    assert main(["fit", str(SCAN), "-o", str(tmp_path / "s.npz"), "--level", "none"]) == 0
    assert main(["export", str(tmp_path / "s.npz"), "-o", str(tmp_path / "s.gwy")]) == 0
    capsys.readouterr()
    back = load_scan(tmp_path / "s.gwy")
    assert back.shape == src.shape
    np.testing.assert_allclose(back.heights, src.heights, rtol=0, atol=1e-18)  # the fit interpolates


def _fails(capsys, argv, *needles):
    """``main(argv)`` returns 2 with one line on stderr holding every needle (no traceback)."""
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in err, err
    return err


def test_a_smoothing_width_wider_than_the_scan_is_reported_in_nanometres(capsys, tmp_path):
    """`--sigma-nm 1e9` was answered in metres ("sigma is in metres (e.g. 2e-9...)") to someone
    who typed nanometres: the CLI restates it in nm, with the scan's width and a usable value."""
    err = _fails(capsys, ["fit", str(SCAN), "-o", str(tmp_path / "s.npz"), "--sigma-nm", "1e9"],
                 "--sigma-nm", "nm", "wider than the scan")
    assert "metres" not in err and "2e-9" not in err
    from arsurf.scan.io import load_scan

    scan = load_scan(SCAN)
    assert f"{scan.shape[1]} pixels, {scan.shape[1] * scan.dx * 1e9:.4g} nm" in err
    _fails(capsys, ["convert", str(SCAN), "-o", str(tmp_path / "c.gsf"), "--sigma-nm", "1e9"], "--sigma-nm")


@pytest.mark.parametrize("value", ["-1", "nan", "inf", "x"])
def test_a_bad_penalty_weight_is_refused_by_its_flag(capsys, value, tmp_path):
    _one_line_error(capsys, ["fit", str(SCAN), "-o", str(tmp_path / "s.npz"), "--smoothing", value], "--smoothing")


def test_the_control_flag_is_named_in_its_error(capsys, tmp_path):
    err = _fails(capsys, ["fit", str(SCAN), "-o", str(tmp_path / "s.npz"), "--control", "3", "3"],
                 "--control", "got (3, 3)")
    assert "control_shape" not in err
    # what the message calls allowed is accepted: the interpolating net and the approximating limit
    from arsurf.scan.io import load_scan

    nx = load_scan(SCAN).shape[1]
    for shape in ((nx + 2, nx + 2), (nx, nx), (4, 4)):
        assert main(["fit", str(SCAN), "-o", str(tmp_path / "s.npz"), "--control", *map(str, shape)]) == 0
    assert main(["fit", str(SCAN), "-o", str(tmp_path / "s.npz"), "--control", str(nx + 2), str(nx + 2),
                 "--smoothing", "1e-3"]) == 0


def test_a_closed_pipe_is_silent_and_exits_cleanly(tmp_path):
    """`arsurf info F | head -1` closes the pipe early; made deterministic by a pipe whose reading end
    is closed before arsurf writes: no traceback, no 'Exception ignored' at exit."""
    import os

    r, w = os.pipe()
    os.close(r)
    try:
        run = subprocess.run([sys.executable, "-m", "arsurf", "info", str(SCAN)], stdout=w, stderr=subprocess.PIPE,
                             text=True, timeout=120, cwd=ROOT)
    finally:
        os.close(w)
    assert run.returncode == 0 and run.stderr == "", run.stderr
    cmd = f"{sys.executable} -m arsurf info {SCAN} | head -1"
    run = subprocess.run(cmd, shell=True, capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert run.stderr == "" and run.stdout.startswith("file"), (run.stdout, run.stderr)


def test_exporting_a_nanosurf_scan_says_to_fit_it_first(capsys, tmp_path):
    """The case the issue found: `arsurf export scan.nid` gave numpy's 'pickled (object) data' error."""
    nid = tmp_path / "scan.nid"
    nid.write_bytes(b"[DataSet]\r\nVersion=2\r\nGroupCount=1\r\n#!" + bytes(64))
    _fails(capsys, ["export", str(nid), "-o", str(tmp_path / "x.stl")], "scan.nid", "arsurf fit")
    _fails(capsys, ["export", str(SCAN), "-o", str(tmp_path / "x.stl")], "arsurf fit")


def test_a_bare_matrix_is_fitted_and_converted_with_its_calibration_flags(capsys, tmp_path):
    import numpy as np

    from arsurf.scan.io import load_scan

    path = tmp_path / "bare.txt"
    np.savetxt(path, np.add.outer(np.arange(8.0), np.arange(9.0)))
    _fails(capsys, ["fit", str(path), "-o", str(tmp_path / "s.npz")], "--dx-nm", "--dy-nm")
    _fails(capsys, ["fit", str(path), "-o", str(tmp_path / "s.npz"), "--dx-nm", "2", "--dy-nm", "2"], "--z-unit")
    _one_line_error(capsys, ["fit", str(path), "-o", "s.npz", "--dx-nm", "-2"], "--dx-nm")
    assert main(["convert", str(path), "-o", str(tmp_path / "c.npz"), "--dx-nm", "2", "--dy-nm", "3",
                 "--z-unit", "nm"]) == 0
    out = load_scan(tmp_path / "c.npz")
    assert (out.dx, out.dy) == pytest.approx((2e-9, 3e-9)) and np.nanmax(out.heights) == pytest.approx(15e-9)
    assert main(["fit", str(path), "-o", str(tmp_path / "s.npz"), "--dx-nm", "2", "--dy-nm", "3",
                 "--z-unit", "nm", "--level", "none"]) == 0
    _fails(capsys, ["info", str(SCAN), "--dx-nm", "3"], "states dx", "remove it")


def test_info_reports_a_current_channel_in_amperes(capsys):
    import json

    assert main(["info", str(real_scan_path("STM_nanonis_generic_4_5.sxm")), "--channel", "Current (forward)",
                 "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["units"]["reported"] == "A" and "z_min_A" in info and not any(k.endswith("_nm") and k.startswith("z_")
                                                                               for k in info)
    assert info["height_channel"].startswith("no")


def test_a_channel_that_is_not_the_topography_is_fitted_only_on_request(capsys, tmp_path):
    """An Asylum AmplitudeRetrace is in metres but is not a height: refused without --as-height;
    PhaseRetrace (degrees) is refused even with it."""
    ibw = str(real_scan_path("AR_20211011.ibw"))
    out = str(tmp_path / "s.npz")
    _fails(capsys, ["fit", ibw, "-o", out, "--channel", "AmplitudeRetrace", "--control", "20", "20"],
           "AmplitudeRetrace", "--as-height")
    assert main(["fit", ibw, "-o", out, "--channel", "AmplitudeRetrace", "--control", "20", "20", "--as-height"]) == 0
    capsys.readouterr()
    _fails(capsys, ["fit", ibw, "-o", out, "--channel", "PhaseRetrace", "--as-height"], "PhaseRetrace", "deg")


@pytest.mark.parametrize("frames", ["0", "2"])
def test_view_frames_name_the_option_and_its_bound(capsys, frames):
    """#30: ``--frames 0`` said "at least 1 frame", ``--frames 2`` "`frames` must be at least 4" (a
    Python name); both now name the CLI option and the one bound, which --help states too."""
    from arsurf.cli.view import MIN_SCRIPTED_FRAMES

    code = main(["view", str(SCAN), "--frames", frames])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert f"--frames {frames}: at least {MIN_SCRIPTED_FRAMES} without --bridge-port" in err and "`frames`" not in err
    with pytest.raises(SystemExit):
        main(["view", "--help"])
    assert f"at least {MIN_SCRIPTED_FRAMES}" in " ".join(capsys.readouterr().out.split())


def test_the_frames_bound_is_the_scripted_paths():
    pytest.importorskip("pyvista")
    from arsurf.cli.view import MIN_SCRIPTED_FRAMES
    from arsurf.errors import ViewerError
    from arsurf.spline.surface import BSplineSurface
    from arsurf_viewer.interactive import scripted_path

    s = BSplineSurface.from_heights(np.zeros((6, 6)), (0.0, 50e-9), (0.0, 50e-9))
    assert scripted_path(s, 20e-9, MIN_SCRIPTED_FRAMES).shape == (MIN_SCRIPTED_FRAMES, 3)
    with pytest.raises(ViewerError):
        scripted_path(s, 20e-9, MIN_SCRIPTED_FRAMES - 1)


def test_info_on_a_fitted_surface_says_it_is_one(capsys, tmp_path):
    """#30: ``arsurf info`` on `arsurf fit`'s output said "no 2-D numeric array"."""
    out = tmp_path / "s.npz"
    assert main(["fit", str(SCAN), "-o", str(out)]) == 0
    capsys.readouterr()
    assert main(["info", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["kind"].startswith("fitted B-spline surface") and info["fitted_from"] == str(SCAN)
    assert info["z_max_nm"] > info["z_min_nm"] and info["deformed"] is False
    assert "x" in info["control_points"]
