"""``arsurf demo --material FILE --zone-energy``: the material demo with the energy of the whole tip
as the contact, each surface element with the map's local law. From the command line, on the
QNM-like file of tests/demo/test_material_demo.py: the stiff press sinks in as the local zone law
says (its depth on a flat), both pull off at its 2 pi R w within the lattice's quadrature, the soft
spot sinks in more and the sticky one holds on more, and the session replays with the same
contacts. (The soft press, 2.4 nm deep under a 5 nm tip, is beyond the small-contact limit, where
the lattice's sum departs from the law by ~20 %: docs/feel.rst.)"""
from __future__ import annotations

import json

import numpy as np
import pytest

from arsurf.cli import main
from tests.support.real_scans import write_qnm_npz

R_NM = 5.0
H = 1e-9
N = 120


@pytest.fixture(scope="module")
def summary(tmp_path_factory):
    """Soft left half (0.3 GPa), stiff right half (8 GPa), a sticky disc in the soft half; flat;
    the channels' units stated in the file."""
    d = tmp_path_factory.mktemp("qnm")
    y, x = np.mgrid[0:N, 0:N] * H
    path = write_qnm_npz(d / "qnm.npz", 0.05e-9 * np.sin(x / 7e-9) * np.cos(y / 9e-9),
                         np.where(x < 60e-9, 0.3e9, 8e9),
                         np.where(np.hypot(x - 30e-9, y - 85e-9) < 12e-9, 12e-9, 3e-9), H)
    with np.load(path) as f:
        arrays = dict(f)
    meta = json.loads(str(arrays["arsurf_meta"]))
    meta["units"] = {"Height": "m", "DMTModulus": "Pa", "Adhesion": "N"}
    np.savez(path, **dict(arrays, arsurf_meta=np.array(json.dumps(meta))))
    out = d / "demo"
    assert main(["demo", "--material", str(path), "--tip-radius-nm", str(R_NM), "--zone-energy", "--no-images",
                 "--out", str(out)]) == 0
    return json.loads((out / "summary.json").read_text())


@pytest.mark.slow  # builds the module fixture
def test_the_presses_follow_the_local_zone_law(summary):
    assert summary["zone_energy"] is True
    s = summary["spots"]
    assert summary["stiff_over_soft_peak_load"] > 3.0 and summary["soft_over_stiff_indentation"] > 3.0
    stiff = s["stiff"]  # a = 0.27 R: within the small-contact limit, where the lattice sums the law to ~1 %
    assert stiff["indentation_at_reference_load_m"] == pytest.approx(stiff["zone_indentation_at_reference_load_m"],
                                                                     rel=0.02)
    for k in ("soft", "stiff"):  # the lattice (0.5 nm) sums the adhesive ring of a 5 nm tip to 5-7 % (docs/feel.rst)
        assert s[k]["pull_off_N"] == pytest.approx(s[k]["zone_pull_off_N"], rel=0.1), k
    assert s["sticky"]["pull_off_N"] < 2.0 * s["soft"]["pull_off_N"] < 0  # the sticky spot holds on
    assert summary["replay_contact_mismatches"] == 0
    assert summary["passivity_reserve_probe_J"] >= summary["reference_law_adhesion_energy_J"] > 0


def test_zone_energy_without_a_material_file_is_refused_in_one_line(capsys):
    assert main(["demo", "--zone-energy", "--no-images"]) != 0
    err = capsys.readouterr().err.strip()
    assert "--material" in err and len(err.splitlines()) == 1
