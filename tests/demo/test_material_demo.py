"""``arsurf demo --material``: on a small QNM-like file the hand presses the soft, stiff and sticky
spots, and the feel differs as the local Maugis-Dugdale laws say (the real file: make demo-material)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from arsurf.contact.material_conversion import MaterialConversion
from tests.support.real_scans import write_qnm_npz
from arsurf.demo import pick_spots, run_material_demo

R = 5e-9
H = 1e-9
N = 120


@pytest.fixture(scope="module")
def qnm(tmp_path_factory):
    """Soft left half (0.3 GPa), stiff right half (8 GPa), a sticky disc in the soft half; flat."""
    d = tmp_path_factory.mktemp("qnm")
    y, x = np.mgrid[0:N, 0:N] * H
    modulus = np.where(x < 60e-9, 0.3e9, 8e9)
    adhesion = np.where(np.hypot(x - 30e-9, y - 85e-9) < 12e-9, 12e-9, 3e-9)
    height = 0.05e-9 * np.sin(x / 7e-9) * np.cos(y / 9e-9)
    return write_qnm_npz(d / "qnm.npz", height, modulus, adhesion, H)


@pytest.fixture(scope="module")
def summary(qnm, tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    return run_material_demo(out, qnm, MaterialConversion(R), images=False,
                             channels={"modulus": "DMTModulus", "adhesion": "Adhesion", "deformation": None,
                                       "dissipation": None}, units={"modulus": "Pa", "adhesion": "N"})


@pytest.mark.slow  # builds the module fixture
def test_the_spots_are_where_the_map_says(summary):
    s = summary["spots"]
    assert s["soft"]["x_m"] < 58e-9 and s["stiff"]["x_m"] > 62e-9
    assert math.hypot(s["sticky"]["x_m"] - 30e-9, s["sticky"]["y_m"] - 85e-9) < 12e-9
    assert s["sticky"]["w_J_per_m2"] > 2 * s["soft"]["w_J_per_m2"]


def test_the_summary_names_the_si_unit_of_every_number(summary, tmp_path):
    """summary.json: every number's key ends with its SI unit (or says it is a count or ratio);
    the map says what it means, and the passivity reserve covers the sticky spot's well."""
    import json

    from arsurf.units import summary_json, undeclared

    written = json.loads(summary_json(summary))
    assert undeclared(written) == []
    assert written["tip_radius_m"] == R and written["rate_Hz"] > 0 and "tip_radius_nm" not in written
    assert written["material"]["convention"].startswith("rigid-tip DMT fit, same probe")
    assert written["passivity_reserve_probe_J"] >= written["reference_law_adhesion_energy_J"] > 0


def test_the_hand_feels_harder_and_stickier_regions(summary):
    s = summary["spots"]
    assert summary["stiff_over_soft_peak_load"] > 3.0                     # the same stroke pushes back harder
    assert summary["soft_over_stiff_indentation"] > 3.0                   # at one load the soft spot sinks in
    assert s["sticky"]["pull_off_N"] < 2.0 * s["soft"]["pull_off_N"] < 0  # and the sticky one holds on
    for k, v in s.items():                                                # each as its local MD law says
        if k != "sticky":   # soft and sticky: the stroke may never make it compressive (no indentation)
            assert v["indentation_at_reference_load_m"] == pytest.approx(v["md_indentation_at_reference_load_m"],
                                                                         rel=0.05), k
        assert v["pull_off_N"] == pytest.approx(v["md_pull_off_load_control_N"], rel=0.05), k
    assert summary["replay_contact_mismatches"] == 0


def test_pick_spots_refuses_nothing_to_pick():
    from arsurf.contact.material_map import build_material_map
    from arsurf.scan.scan import Scan

    n = 20   # 20 nm square: nothing is 4 R from the border
    chans = {"modulus": Scan(np.full((n, n), 1e9), H, H, "DMTModulus", {"z_unit": "Pa"}),
             "adhesion": Scan(np.full((n, n), 2e-9), H, H, "Adhesion", {"z_unit": "N"})}
    height = Scan(np.zeros((n, n)), H, H)
    with pytest.raises(ValueError, match="no candidate"):
        pick_spots(build_material_map(height, chans, MaterialConversion(R)), height, R)
