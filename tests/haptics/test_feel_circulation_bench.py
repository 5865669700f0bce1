"""``bench/feel_circulation.py``: the work the contact force does round a closed loop of the target
(docs/feel-log.rst, "Where the rough runs' energy comes from")."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.model import ARModel
from arsurf.scan import synthetic
from arsurf.spline.fit import fit_surface
from support.benches import SLIDE_KEY, load_bench, run_on_row
from support.valleys import LEVER, R, height_for, pressed_onto, valley_model



@pytest.fixture(scope="module")
def circulation():
    return load_bench("feel_circulation")


def test_one_contact_on_a_flat_does_no_work_round_a_loop(circulation):
    """One contact on a flat behind a coupling: the force is the gradient of the contact's potential
    in series with the coupling's (tests/contact/test_force_field.py), so a turn gives back what it
    took, in every plane, to rounding."""
    flat = fit_surface(synthetic.sinusoid(shape=(40, 40), pixel=1e-9, amplitude=0.0, period=10e-9))
    m = ARModel(flat, R, MaugisDugdale(R, 50e9, 0.05), LEVER, friction=0.0, deform=False, coupling_stiffness=5.0)
    c = np.array([20e-9, 20e-9, R - 1.0e-9])
    pressed_onto(m, c)
    for plane in ("xz", "yz"):
        w = circulation.loop_work(m, c, 0.3e-9, plane, points=400)
        assert w["absolute_work_J"] > 0.0 and abs(w["circulation"]) <= 1e-9, w
        assert w["memory"] <= 1e-9
    w = circulation.loop_work(m, c, 0.3e-9, "xy", points=400)  # level on a flat: no work at all
    assert w["absolute_work_J"] <= 1e-12 * circulation.loop_work(m, c, 0.3e-9, "xz", points=400)["absolute_work_J"]


def test_in_a_valley_narrower_than_the_tip_the_work_of_a_turn_is_the_curl_the_jacobian_gives(circulation):
    """The several-contact force in a valley narrower than the tip is not a gradient (the strict
    xfail of tests/contact/test_force_field.py). Round a small loop across the valley and up its
    walls the force's work is, by Stokes' theorem, its curl times the loop's area,
    :math:`(\\partial F_z/\\partial x - \\partial F_x/\\partial z)\\,\\pi r^2` from the model's own
    Jacobian; with no memory of the path, the loop run clockwise gives the work back with the other
    sign; along the valley (the sinusoid is straight along y) there is none."""
    m = valley_model("sinusoid", coupling=5.0)
    c = np.array([33.8e-9, 24e-9, height_for("sinusoid", 33e-9, 2e-9)])
    pressed_onto(m, c)
    r = 0.1e-9
    jac = m.force_jacobian(c - [r, 0.0, 0.0])  # at the loop's centre; J[i, j] = dF_i/dC_j
    ccw = circulation.loop_work(m, c, r, "xz", points=800)
    cw = circulation.loop_work(m, c, r, "xz", points=800, sense=-1)
    assert ccw["lap_work_J"] == pytest.approx((jac[2, 0] - jac[0, 2]) * math.pi * r * r, rel=0.05)
    assert abs(ccw["circulation"]) >= 1e-3, ccw  # this model's valley: ~1 % of the work (docs/feel-log.rst)
    assert ccw["memory"] <= 1e-6 and cw["memory"] <= 1e-6
    assert cw["lap_work_J"] == pytest.approx(-ccw["lap_work_J"], rel=1e-3)
    along = circulation.loop_work(m, c, r, "yz", points=800)
    assert abs(along["circulation"]) <= 1e-6, along


def test_the_bench_reads_a_table_row_and_refuses_bad_arguments(tmp_path):
    key, table = SLIDE_KEY, tmp_path / "rows.jsonl"
    row = {"key": key, "kind": "fast", "ok": False}
    done = run_on_row("feel_circulation.py", table, row, "--points", "64", timeout=300)
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert out["radius_m"] == pytest.approx(3e-9) and out["friction"] == 0.0
    (surface,) = out["surfaces"]
    assert surface["keys"] == [key] and surface["tip_radius_m"] == pytest.approx(2.26e-9, rel=1e-2)
    assert set(surface["planes"]) == {"xy", "xz", "yz"}
    for w in surface["planes"].values():
        assert w["median_force_N"] > 0.0 and w["absolute_work_J"] > 0.0
        assert abs(w["lap_work_J"]) <= w["absolute_work_J"] and math.isclose(
            w["circulation"], w["lap_work_J"] / w["absolute_work_J"], rel_tol=1e-12)
    done = run_on_row("feel_circulation.py", table, row, "--radius", "-1", timeout=60)
    assert done.returncode == 1 and done.stderr.count("\n") == 1 and "--radius" in done.stderr
