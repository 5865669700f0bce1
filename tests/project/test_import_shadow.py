"""A script beside the clone still imports the package (issue #30, "Traps").

``git clone`` names the checkout ``arsurf``; a script run from the folder holding it had that
folder first on ``sys.path``, where the checkout (no ``__init__.py``) became a namespace package
``arsurf`` and hid the editable install: ``module 'arsurf' has no attribute 'load_scan'``.
``make setup`` puts the checkout on the path (``tools/editable_root.py``), so the path search
meets ``arsurf/__init__.py`` and the regular package wins. Reproduced here as it happened: a
folder named ``arsurf`` that is this checkout (a link), a script beside it, the test's interpreter
(the environment ``make setup`` made), no ``PYTHONPATH``.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

SCRIPT = """
import arsurf, arsurf_viewer
print(arsurf.load_scan.__module__, arsurf.__file__)
"""


def test_a_script_beside_a_clone_named_arsurf_imports_the_package(tmp_path):
    try:
        (tmp_path / "arsurf").symlink_to(ROOT, target_is_directory=True)
    except OSError as exc:  # pragma: no cover - a file system without links
        pytest.skip(f"cannot make a symbolic link here: {exc}")
    (tmp_path / "analysis.py").write_text(SCRIPT)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONSAFEPATH")}
    run = subprocess.run([sys.executable, "analysis.py"], cwd=tmp_path, env=env, capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 0, run.stderr.strip().splitlines()[-1:]
    module, where = run.stdout.split()
    assert module == "arsurf.scan.io" and Path(where).name == "__init__.py"
