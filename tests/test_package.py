"""Packaging promises: every public name resolves, the engine never imports the viewer,
every package folder is listed in pyproject.toml."""
import subprocess
import sys
import tomllib
from pathlib import Path

import arsurf

ROOT = Path(__file__).resolve().parents[1]


def test_every_public_name_resolves():
    for name in arsurf.__all__:
        assert getattr(arsurf, name) is not None, name


def test_import_arsurf_does_not_import_pyvista_or_compile_anything():
    code = ("import sys, arsurf; arsurf.fit_surface; arsurf.collide; arsurf.HapticLoop; "
            "print('pyvista' in sys.modules, 'vtk' in sys.modules, 'matplotlib' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["False", "False", "False"]


def test_every_package_folder_is_listed_in_pyproject():
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "arsurf").rglob("__init__.py")}
    found.add("arsurf_viewer")
    assert found <= listed, found - listed


def test_numba_cache_is_keyed_on_the_sources(tmp_path):
    import os

    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["XDG_CACHE_HOME"] = str(tmp_path)
    code = "import os, arsurf; print(os.environ['NUMBA_CACHE_DIR'])"
    folder = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                            check=True).stdout.strip()
    assert folder.startswith(str(tmp_path / "arsurf" / f"numba-{arsurf.__version__}-")) and len(folder.split("-")[-1]) == 16
    env["NUMBA_CACHE_DIR"] = str(tmp_path / "mine")
    kept = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert kept.stdout.strip() == str(tmp_path / "mine")


def test_the_replay_package_and_the_replay_function_have_their_own_names():
    import types

    import arsurf
    from arsurf.replay.replay import replay

    assert isinstance(arsurf.replay, types.ModuleType)
    assert arsurf.replay_session is replay
    import arsurf.replay.plots  # noqa: F401 (importing a submodule must not change what arsurf.replay is)

    assert isinstance(arsurf.replay, types.ModuleType)
