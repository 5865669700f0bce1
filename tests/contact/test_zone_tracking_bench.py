"""The zone energy's tracking proxy bench (bench/zone_tracking.py; docs/performance.rst, "One sum
of the lattice a tick"): on a real scan's 100 nm/s slide each tick takes one Newton step, one sum
of the lattice, and the force it publishes is the converged proxy's within a thousandth of the
peak."""
from __future__ import annotations

import json

from tests.support.benches import load_bench
from tests.support.real_scans import real_scan_path


def test_one_step_a_tick_and_the_converged_force_within_a_thousandth(capsys):
    name = real_scan_path("2018-02-09_1506_PH_dt20nmwindow1_Z_C.gsf").name
    load_bench("zone_tracking").main(["--scans", name, "--motions", "slide-100", "--seconds", "1.2"])
    (row,) = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert row["ticks"] > 800 and row["peak_force_N"] > 1e-8
    assert row["newton_steps_per_tick_mean"] == 1.0
    assert 0.1 < row["published_off_the_summed_point_share"] < 1.0
    assert max(row["largest_difference_over_peak"]) < 1e-3
