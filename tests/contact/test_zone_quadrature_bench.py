"""The zone energy's quadrature benches (docs/feel.rst, "The lattice's quadrature"): what they
print is what the manual quotes - the model's lattice sums the law on a flat within 2 % where R/8
is far off (bench/zone_quadrature.py), and an element's mean of the law sums it better than its
point value on the same lattice (bench/zone_element_average.py); bench/zone_sum_cost.py counts
the samples it times."""
from __future__ import annotations

import json

import pytest

from tests.support.benches import load_bench


def _rows(capsys) -> list[dict]:
    return [json.loads(line) for line in capsys.readouterr().out.splitlines()]


def test_the_model_s_lattice_sums_the_law_where_r_over_8_does_not(capsys):
    load_bench("zone_quadrature").main(["--radii-nm", "20", "--pixels-nm", "4"])
    (row,) = _rows(capsys)
    assert row["lattice_for"]["spacing_m"] == pytest.approx(row["zone_over_8"]["spacing_m"], rel=0.01)
    assert row["lattice_for"]["worst_error_percent"] <= 2.0
    assert row["radius_over_8"]["worst_error_percent"] >= 50.0
    assert row["lattice_for"]["samples_at_the_deepest_press"] > 10 * row["radius_over_8"]["samples_at_the_deepest_press"]


def test_an_element_s_mean_sums_the_law_better_than_its_point(capsys):
    load_bench("zone_element_average").main(["--radii-nm", "20"])
    rows = {r["spacing"]: r for r in _rows(capsys)}
    quarter = rows["zone_over_4"]
    assert quarter["point_worst_error_percent"] > 5.0
    assert quarter["trapezoid_curvature_worst_error_percent"] < 1.0
    assert quarter["box_curvature_worst_error_percent"] < 1.0
    assert rows["zone_over_8"]["point_worst_error_percent"] < 2.0  # the engine's rule, summed here the same way


def test_the_sum_cost_bench_times_the_samples_it_names(capsys):
    load_bench("zone_sum_cost").main()
    rows = _rows(capsys)
    assert [r["depth_m"] for r in rows] == [0.3e-9, 1.0e-9]
    for r in rows:
        assert r["vector_samples_visited"] >= r["samples_in_reach"] > 100  # the square covers the disc in reach
        assert r["engine_sum_with_hessian_s"] > 0.0 and r["vector_sum_s"] > 0.0
    assert rows[1]["samples_in_reach"] > rows[0]["samples_in_reach"]  # pressed deeper, a wider contact
