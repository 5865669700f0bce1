"""``bench/zone_energy.py``: the model's force and the zone energy's (arsurf.contact.zone_energy)
swept where a families table fails (docs/feel.rst, "The next step")."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from support.benches import BENCH as BENCHES, load_bench

BENCH = BENCHES / "zone_energy.py"


def test_a_step_is_a_change_beyond_the_threshold_of_the_median_force():
    bench = load_bench("zone_energy")
    force = np.zeros((6, 3))
    force[:, 2] = [1.0, 1.0, 1.005, 1.2, 1.2, 0.0]  # a 0.5 % change, a 19.5 % one, and a release
    got = bench.step_figures(force, 0.01)
    assert got["median_force_N"] == pytest.approx(1.005)  # where it touches
    assert got["steps"] == 2 and got["largest_step_over_force"] == pytest.approx(1.2 / 1.005)
    assert bench.step_figures(np.zeros((4, 3)), 0.01)["steps"] == 0  # never touching: none


def test_the_bench_reads_a_table_row_and_refuses_bad_arguments(tmp_path):
    key = "5:1:1:power-law#613753790 h=0.599nm l=7.15nm px=0.944nm R=2.26nm"  # plan_table(4, 5, runs 1 1): slide-100
    table = tmp_path / "rows.jsonl"
    table.write_text(json.dumps({"key": key, "kind": "fast", "ok": False}) + "\n")
    plan = ["--families", "4", "--runs", "1", "1", "--seed", "5"]
    done = subprocess.run([sys.executable, str(BENCH), str(table), *plan, "--length", "0.2"], capture_output=True,
                          text=True, timeout=300)
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
    done = subprocess.run([sys.executable, str(BENCH), str(table), *plan, "--per-knot", "0"], capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 1 and done.stderr.count("\n") == 1 and "--per-knot" in done.stderr
