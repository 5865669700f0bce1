"""``arsurf devices``: one line per backend, exit 0 whatever is installed or connected; with the
simulated vendor libraries on the library paths it lists the simulated devices."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support import hardware_sim

ROOT = Path(__file__).resolve().parents[2]


def _devices(env_extra: dict, *args) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("FDSDK", "FORCEDIM_SDK", "LD_LIBRARY_PATH")}
    env.update(env_extra)
    return subprocess.run([sys.executable, "-m", "arsurf", "devices", *args], capture_output=True, text=True,
                          env=env, timeout=300, cwd=ROOT)


def test_nothing_installed_or_connected_is_not_an_error(tmp_path):
    out = _devices({"HOME": str(tmp_path)})
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    names = [line.split()[0] for line in lines]
    assert names == ["virtual", "forcedimension", "haply", "openhaptics"]
    for line in lines[1:]:
        assert ("not available:" in line and ("install" in line or "FDSDK" in line)) or "none connected" in line, line


def test_the_simulated_devices_are_listed(tmp_path):
    if hardware_sim.CC is None:
        pytest.skip(hardware_sim.NO_COMPILER)
    if not all(__import__("importlib.util").util.find_spec(m) for m in ("forcedimension_core", "pyOpenHaptics")):
        pytest.skip("forcedimension-core and pyopenhaptics are needed (pip install 'arsurf[hardware]')")
    sdk, _ = hardware_sim.build_fdsdk(tmp_path / "fd")
    hd = hardware_sim.build_libhd(tmp_path / "hd")
    out = _devices({"FDSDK": str(sdk), "LD_LIBRARY_PATH": str(hd.parent), "HOME": str(tmp_path)})
    assert out.returncode == 0, out.stderr
    lines = {line.split()[0]: line for line in out.stdout.splitlines()}
    assert "SDK 3.17.0" in lines["forcedimension"] and "#0 omega.3 s/n 4242" in lines["forcedimension"]
    assert "'Default Device': 3D Systems Touch" in lines["openhaptics"]
    js = _devices({"FDSDK": str(sdk), "LD_LIBRARY_PATH": str(hd.parent), "HOME": str(tmp_path)}, "--json")
    reports = {r["backend"]: r for r in json.loads(js.stdout)}
    (fd,) = reports["forcedimension"]["devices"]
    assert fd.startswith("#0 omega.3 s/n 4242") and reports["openhaptics"]["installed"]
    # where the watchdog and the workspace came from are shown (the bring-up's first checks)
    assert "watchdog_set yes" in fd and "workspace_source kinematics" in fd


def test_json_lists_every_backend_the_text_lists(tmp_path):
    """#30: ``--json`` had no ``virtual`` entry although the text listed it first."""
    text = [line.split()[0] for line in _devices({"HOME": str(tmp_path)}).stdout.splitlines()]
    js = json.loads(_devices({"HOME": str(tmp_path)}, "--json").stdout)
    assert [r["backend"] for r in js] == text and text[0] == "virtual" and js[0]["installed"]
