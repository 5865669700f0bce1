"""``bench/zone_energy.py``: the model's force and the zone energy's (arsurf.contact.zone_energy)
swept where a families table fails (docs/feel-log.rst, "The tip's energy summed over the surface")."""
from __future__ import annotations

import json

import numpy as np
import pytest

from support.benches import SLIDE_KEY, load_bench, run_on_row



def test_a_step_is_a_change_beyond_the_threshold_of_the_median_force():
    bench = load_bench("zone_energy")
    force = np.zeros((6, 3))
    force[:, 2] = [1.0, 1.0, 1.005, 1.2, 1.2, 0.0]  # a 0.5 % change, a 19.5 % one, and a release
    got = bench.step_figures(force, 0.01)
    assert got["median_force_N"] == pytest.approx(1.005)  # where it touches
    assert got["steps"] == 2 and got["largest_step_over_force"] == pytest.approx(1.2 / 1.005)
    assert bench.step_figures(np.zeros((4, 3)), 0.01)["steps"] == 0  # never touching: none


def test_the_bench_reads_a_table_row_and_refuses_bad_arguments(tmp_path):
    key, table = SLIDE_KEY, tmp_path / "rows.jsonl"
    row = {"key": key, "kind": "fast", "ok": False}
    done = run_on_row("zone_energy.py", table, row, "--length", "0.2", timeout=300)
    assert done.returncode == 0, done.stderr
    (run,) = json.loads(done.stdout)["runs"]
    assert run["key"] == key and run["coupling_N_per_m"] > 0.0
    for side in ("coupled", "rigid"):
        for name, figures in run[side].items():
            assert figures["median_force_N"] > 0.0, (side, name)
    proxy = run["coupled"]["zone_proxy"]
    assert proxy["not_converged"] == 0 and proxy["snaps"] == 0 and proxy["steps"] == 0  # a smooth 0.6 nm surface
    zone = run["rigid"]["zone"]
    assert zone["lattice_spacing_m"] <= 2.26e-9 / 8 and zone["samples_in_reach_median"] > 0
    assert zone["evaluation_us"] > 0.0 and zone["vtk_query_us"] > 0.0
    done = run_on_row("zone_energy.py", table, row, "--per-knot", "0", timeout=60)
    assert done.returncode == 1 and done.stderr.count("\n") == 1 and "--per-knot" in done.stderr


def test_the_feel_bench_judges_a_table_row_with_the_zone_proxy_and_refuses_bad_arguments(tmp_path):
    """``bench/zone_feel.py``: the row judged again, each loop's contact the zone energy's proxy; on
    this smooth slide both loops pass, and the zone loop's 1 and 10 kHz forces agree."""
    row = {"key": SLIDE_KEY, "kind": "fast", "ok": True, "rate_error": 0.001}
    done = run_on_row("zone_feel.py", tmp_path / "rows.jsonl", row, "--all")
    assert done.returncode == 0, done.stderr
    (run,) = json.loads(done.stdout)["runs"]
    assert run["key"] == SLIDE_KEY and run["motion"] == "slide-100" and run["table"]["rate_error"] == 0.001
    assert run["zone"]["ok"] and 0.0 <= run["zone"]["rate_error"] <= 0.05
    done = run_on_row("zone_feel.py", tmp_path / "rows.jsonl", row, "--all", "--control")
    assert done.returncode == 0, done.stderr
    (control,) = json.loads(done.stdout)["runs"]
    assert "zone" not in control and control["control"]["ok"]  # the model, friction off: passes here too
    done = run_on_row("zone_feel.py", tmp_path / "rows.jsonl", row, "--per-knot", "65", timeout=60)
    assert done.returncode == 1 and done.stderr.count("\n") == 1 and "--per-knot" in done.stderr
