"""The batch tests' inputs: tiny synthetic scans (a folder with one truncated file and one that
is not a scan) and short recorded sessions. Metres."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from arsurf.scan import synthetic
from arsurf.scan.io import save_scan


def _scan(k: int):
    return synthetic.sinusoid(shape=(14, 18), pixel=5e-9, amplitude=2e-9, period=50e-9, phase=0.7 * k)


@pytest.fixture
def folder(tmp_path):
    """Three good scans (.gsf, .npz, .gwy), one truncated .gsf and a text file that is not a scan."""
    d = tmp_path / "scans"
    d.mkdir()
    for k, ext in enumerate(("gsf", "npz", "gwy")):
        save_scan(_scan(k), d / f"s{k}.{ext}")
    good = (d / "s0.gsf").read_bytes()
    (d / "broken.gsf").write_bytes(good[: len(good) // 2])
    (d / "notes.md").write_text("not a scan\n")
    return d


def _session(path: Path, scan: str, depth: float):
    """A short press and release at the middle of ``scan`` (the demo preset), ``scan`` as recorded."""
    from arsurf.assembly import preset_metadata
    from arsurf.sessions.writer import SessionWriter

    meta = preset_metadata(scan, "demo")
    n = 30
    z = 2e-9 + 20e-9 + 1e-9 - depth * np.sin(np.linspace(0, np.pi, n))  # R = 20 nm; the peaks are ~2 nm high
    with SessionWriter(path, meta, created="2000-01-01T00:00:00Z") as w:
        for k in range(n):
            w.append(t=k * 1e-3, probe_position=(40e-9, 30e-9, z[k]), probe_velocity=(0.0, 0.0, 0.0))
    return path
