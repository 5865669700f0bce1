"""The CLI never leaks a traceback and never silently accepts nonsense (issue #14 §4): every
error is one line on stderr naming the flag or file, with exit status 2."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from conftest import real_scan_path

from arsurf import __version__
from arsurf.cli import main

ROOT = Path(__file__).resolve().parents[1]
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
