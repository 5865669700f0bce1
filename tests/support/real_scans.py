"""The real AFM files in ../shared/scans-real (third-party data, never copied into the project) and
a QNM-like sample writer. ``ARSURF_REAL_SCANS`` points elsewhere."""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

REAL_SCANS = Path(os.environ.get("ARSURF_REAL_SCANS", Path(__file__).resolve().parents[3] / "shared" / "scans-real"))


def real_scan_path(name: str) -> Path:
    """Path of a real scan in ../shared/scans-real, or skip the test saying why."""
    path = REAL_SCANS / name
    if not path.exists():
        pytest.skip(f"real scan {name!r} not found in {REAL_SCANS} (../shared is absent; CI always has it)")
    return path


def write_qnm_npz(path, height, modulus, adhesion, pixel: float) -> Path:
    """A PeakForce-QNM-like .npz (Height, DMTModulus, Adhesion arrays on one grid of ``pixel``
    metres): it states the spacing and that heights are in metres, not the mechanical channels'
    units (pass them as ``units``)."""
    np.savez(path, Height=height, DMTModulus=modulus, Adhesion=adhesion,
             arsurf_meta=np.array(json.dumps({"dx": pixel, "dy": pixel, "units": {"Height": "m"}})))
    return Path(path)
