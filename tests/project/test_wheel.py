"""``pip install arsurf`` works without the source tree.

The wheel is built from the sources (a copy of the files git knows, so no stale ``build/``),
installed into a fresh venv, and run from an empty temporary folder with no ``PYTHONPATH``:
``arsurf --version``, ``python -m arsurf``, ``arsurf view`` headless and ``arsurf demo`` must
work from the installed files alone (the demo's scan is package data), and the demo must write
the same files as the demo run from the sources, with the same numbers in ``summary.json``
(wall-clock timings apart) and the same replayed forces, byte for byte.

The venv has no copy of numpy, scipy, numba, VTK...: a ``.pth`` line puts the site-packages of
the interpreter running the tests after its own (only the folder, so the editable install of the
sources that may live there is not loaded), and the test checks that ``arsurf`` and
``arsurf_viewer`` are imported from the venv, and that every core dependency the wheel declares
is installed. Runtime: ~1-2 min (the demo twice, in parallel; numba compiles the installed
kernels once). Marked ``wheel``: ``-m "not wheel"`` skips it; without a local setuptools >= 77
the build needs the package index and is skipped when that is unreachable.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

pytestmark = pytest.mark.wheel  # every subprocess has its own timeout

ROOT = Path(__file__).resolve().parents[2]
#: summary.json keys that hold wall-clock measurements (differ between any two runs)
TIMING_KEYS = ("wall_time_s", "tick_compute_median_s", "tick_compute_p99_s")
#: keys that hold where the files were (the scan's and the session's paths and hashes of the session)
LOCATION_KEYS = ("scan", "path", "session_sha256")


def _run(cmd, *, cwd, env, timeout=300, check=True) -> subprocess.CompletedProcess:
    proc = subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    if check and proc.returncode != 0:
        raise AssertionError(f"{' '.join(map(str, cmd))} exited {proc.returncode}:\n{proc.stdout[-3000:]}\n"
                             f"{proc.stderr[-3000:]}")
    return proc


def _clean_env(**extra) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "PYTHONSTARTUP")}
    env.update(extra)
    return env


def _copy_sources(dest: Path) -> Path:
    """The files git tracks or would track (not ignored) under ROOT, copied to ``dest``."""
    listed = None
    if shutil.which("git") and (ROOT / ".git").exists():
        proc = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=ROOT,
                              capture_output=True)
        if proc.returncode == 0:
            listed = [name for name in proc.stdout.decode().split("\0") if name]
    if listed is None:  # an unpacked source archive: everything but the usual droppings
        ignore = shutil.ignore_patterns(".git", ".venv", "build", "dist", "*.egg-info", "__pycache__", "out")
        shutil.copytree(ROOT, dest, ignore=ignore)
        return dest
    for name in listed:
        src = ROOT / name
        if src.is_file():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / name)
    return dest


def _local_setuptools_builds() -> bool:
    try:
        from importlib.metadata import version

        major = int(version("setuptools").split(".")[0])
    except Exception:
        return False
    return major >= 77  # pyproject's build-system requirement (SPDX license, bdist_wheel built in)


def _build_wheel(src: Path, out: Path) -> Path:
    cmd = [sys.executable, "-m", "pip", "wheel", src, "--no-deps", "-w", out, "--disable-pip-version-check", "-q"]
    if _local_setuptools_builds():
        cmd.append("--no-build-isolation")  # no download: the test extra declares setuptools
    proc = _run(cmd, cwd=src, env=_clean_env(), check=False)
    if proc.returncode != 0:
        text = proc.stdout + proc.stderr
        if any(s in text for s in ("No matching distribution", "Could not find a version", "NewConnectionError",
                                   "Temporary failure in name resolution", "Network is unreachable")):
            pytest.skip("building the wheel needs setuptools>=77 from the package index, which is unreachable "
                        "(pip install 'setuptools>=77' to build offline)")
        raise AssertionError(f"pip wheel failed:\n{text[-4000:]}")
    wheels = sorted(out.glob("arsurf-*.whl"))
    assert len(wheels) == 1, wheels
    return wheels[0]


@pytest.fixture(scope="module")
def wheel_venv(tmp_path_factory):
    """(venv python, venv bin folder, the wheel): arsurf installed from its wheel, nothing else."""
    base = tmp_path_factory.mktemp("wheel")
    wheel = _build_wheel(_copy_sources(base / "src"), base / "dist")
    venv = base / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", venv], cwd=base, env=_clean_env())
    bindir = venv / ("Scripts" if os.name == "nt" else "bin")
    py = bindir / ("python.exe" if os.name == "nt" else "python")
    # pip of this interpreter installs into the venv; --no-deps: the dependencies come from the .pth below
    _run([sys.executable, "-m", "pip", "--python", py, "install", "--no-deps", "--no-index", "-q",
          "--disable-pip-version-check", wheel], cwd=base, env=_clean_env())
    site = Path(_run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], cwd=base,
                     env=_clean_env()).stdout.strip())
    ours = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (site / "zz_parent_site.pth").write_text("".join(f"{p}\n" for p in sorted(ours)))
    return py, bindir, wheel


def test_the_wheel_carries_the_demo_scan_and_no_source_tree_file(wheel_venv):
    import zipfile

    names = zipfile.ZipFile(wheel_venv[2]).namelist()
    assert "arsurf/data/nanotubes.npz" in names and "arsurf/haptics/client.py" in names
    assert "arsurf_viewer/view.py" in names
    assert not [n for n in names if n.startswith(("tests/", "tools/", "scans/", "bench/"))]


def test_installed_arsurf_imports_from_the_venv_with_its_declared_dependencies(wheel_venv, tmp_path):
    py, _, _ = wheel_venv
    code = r"""
import json, sys, importlib.metadata as md
from packaging.requirements import Requirement
import arsurf, arsurf_viewer, arsurf.data
missing = []
for text in md.requires("arsurf"):
    req = Requirement(text)
    if req.marker is not None and not req.marker.evaluate({"extra": ""}):
        continue  # an extra
    try:
        if md.version(req.name) not in req.specifier:
            missing.append(f"{req} (have {md.version(req.name)})")
    except md.PackageNotFoundError:
        missing.append(str(req))
print(json.dumps({"arsurf": arsurf.__file__, "viewer": arsurf_viewer.__file__, "scan": str(arsurf.data.bundled_scan()),
                  "path": sys.path, "missing": missing, "requires": md.requires("arsurf")}))
"""
    info = json.loads(_run([py, "-c", code], cwd=tmp_path, env=_clean_env()).stdout)
    venv = str(py.parent.parent)
    assert info["arsurf"].startswith(venv) and info["viewer"].startswith(venv) and info["scan"].startswith(venv)
    assert not [p for p in info["path"] if p and Path(p).resolve() == ROOT]
    assert info["missing"] == []
    assert any(r.startswith("tqdm") for r in info["requires"])
    assert not any(r.startswith(("imageio", "pyvista")) and "extra" not in r for r in info["requires"])


def test_version_and_python_dash_m_from_the_wheel(wheel_venv, tmp_path):
    py, bindir, _ = wheel_venv
    import arsurf

    want = f"arsurf {arsurf.__version__}"
    assert _run([bindir / "arsurf", "--version"], cwd=tmp_path, env=_clean_env()).stdout.strip() == want
    assert _run([py, "-m", "arsurf", "--version"], cwd=tmp_path, env=_clean_env()).stdout.strip() == want


def _files(folder: Path) -> list[str]:
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())


def _compare(a, b, where="summary"):
    """Equal JSON values, floats exactly, timings and file locations apart (their names compared)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and sorted(a) == sorted(b), (where, sorted(a), sorted(b) if isinstance(b, dict) else b)
        for key in a:
            if key in TIMING_KEYS:
                continue
            if key in LOCATION_KEYS and isinstance(a[key], str):
                assert Path(a[key]).name == Path(b[key]).name or key == "session_sha256", (where, key)
                continue
            _compare(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), where
        for k, (x, y) in enumerate(zip(a, b)):
            _compare(x, y, f"{where}[{k}]")
    elif isinstance(a, float) and a != a:  # NaN (json.dumps writes it): equal when both are
        assert isinstance(b, float) and b != b, (where, a, b)
    else:
        assert a == b, (where, a, b)


@pytest.mark.slow
def test_demo_from_the_wheel_writes_what_the_sources_write(wheel_venv, tmp_path):
    _, bindir, _ = wheel_venv
    run_dir = tmp_path / "cwd"
    run_dir.mkdir()
    flags = ["demo", "--seconds", "6"]
    source_env = _clean_env(PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep))
    # the two demos at once (2 cores): the wheel's kernels compile while the sources' run
    procs = {
        "wheel": subprocess.Popen([str(bindir / "arsurf"), *flags, "--out", str(tmp_path / "wheel")], cwd=run_dir,
                                  env=_clean_env(DISPLAY=""), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                  text=True),
        "sources": subprocess.Popen([sys.executable, "-m", "arsurf", *flags, "--out", str(tmp_path / "sources")],
                                    cwd=run_dir, env=dict(source_env, DISPLAY=""), stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, text=True),
    }
    results = {}
    try:
        for name, proc in procs.items():
            out, err = proc.communicate(timeout=500)
            results[name] = (proc.returncode, out, err)
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    for name, (code, out, err) in results.items():
        assert code == 0, f"{name} demo exited {code}:\n{out[-2000:]}\n{err[-3000:]}"
    wheel, sources = tmp_path / "wheel", tmp_path / "sources"
    assert _files(wheel) == _files(sources)
    assert {"summary.json", "session.h5", "replay/forces.csv", "replay/summary.json"} <= set(_files(wheel))
    assert _files(run_dir) == []  # nothing written where it ran
    summaries = [json.loads((d / "summary.json").read_text()) for d in (wheel, sources)]
    _compare(*summaries)
    assert summaries[0]["scan"].startswith(str(bindir.parent))  # the wheel's demo read its packaged scan
    _compare(*[json.loads((d / "replay" / "summary.json").read_text()) for d in (wheel, sources)], "replay")
    assert (wheel / "replay" / "forces.csv").read_bytes() == (sources / "replay" / "forces.csv").read_bytes()


def test_view_runs_headless_from_the_wheel(wheel_venv, tmp_path):
    """`arsurf view` (the bundled scan) renders offscreen frames, or exits non-zero saying what to install.

    After the demo test: the installed kernels are compiled by then."""
    _, bindir, _ = wheel_venv
    proc = _run([bindir / "arsurf", "-q", "view", "--frames", "4", "--out", "frames"], cwd=tmp_path,
                env=_clean_env(DISPLAY=""), check=False)
    if proc.returncode == 0:
        assert [p.name for p in sorted((tmp_path / "frames").glob("*.png"))] == [f"frame_0000{k}.png" for k in range(4)]
    else:  # no OpenGL here: one line, what to install
        lines = proc.stderr.strip().splitlines()
        assert proc.returncode == 2 and len(lines) == 1 and "install" in lines[0], proc.stderr
