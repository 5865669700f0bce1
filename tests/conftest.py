"""Shared fixtures: the real scans in ../shared/scans-real (never copied into the project)."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REAL_SCANS = Path(os.environ.get("ARSURF_REAL_SCANS", Path(__file__).resolve().parents[2] / "shared" / "scans-real"))


def real_scan_path(name: str) -> Path:
    """Path of a real scan in ../shared/scans-real, or skip the test saying why."""
    path = REAL_SCANS / name
    if not path.exists():
        pytest.skip(f"real scan {name!r} not found in {REAL_SCANS} (../shared is absent; CI always has it)")
    return path


@pytest.fixture
def real_scans_dir() -> Path:
    if not REAL_SCANS.is_dir():
        pytest.skip(f"{REAL_SCANS} is absent (../shared is not beside the project; CI always has it)")
    return REAL_SCANS


def write_qnm_npz(path, height, modulus, adhesion, pixel: float) -> Path:
    """A PeakForce-QNM-like .npz (Height, DMTModulus, Adhesion arrays on one grid of ``pixel``
    metres): it states the spacing and that heights are in metres, not the mechanical channels'
    units (pass them as ``units``)."""
    import json

    np.savez(path, Height=height, DMTModulus=modulus, Adhesion=adhesion,
             arsurf_meta=np.array(json.dumps({"dx": pixel, "dy": pixel, "units": {"Height": "m"}})))
    return Path(path)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20261121)


@pytest.fixture(scope="module")
def gl():
    """An OpenGL context for the viewer's rendering tests (skipped, saying why, without one)."""
    from arsurf_viewer.backend import probe

    result = probe()
    if not result.ok:
        pytest.skip(f"no OpenGL context can be made here: {result.detail}")
    return result
