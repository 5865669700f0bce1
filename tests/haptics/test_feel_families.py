"""The feel judged over generated families of surfaces (issue 27 §3), a seeded CI-size sample of
``bench/feel.py --families``: on each generated surface (random rough of a Gaussian or power-law
spectrum, step, ridge, with its own tip radius) the default loop a user gets - the virtual device,
virtual coupling and passivity on - must keep a still or slowly sliding tip free of buzz (content
above 100 Hz <= 2 % of the mean normal force per axis after 1 s, no tick-to-tick reversal above
1 % of the peak, energy >= -E0, at rest K_f F within 1 %) and give a faster motion a force that
converges in the loop rate."""
from __future__ import annotations

import math

import numpy as np
import pytest

from arsurf.feel_scenarios import (FAMILIES, LENGTH_RANGE, PIXEL_RANGE, RATE_TOLERANCE, RMS_RANGE, SLOW_MOTIONS,
                                   TIP_RANGE, GENERATED_PIXELS, _fold, _trajectory, clearance_height,
                                   generated_surfaces, judge_run,
                                   plan_runs, rate_convergence, rate_difference)

SAMPLE = generated_surfaces(4, seed=27)


def test_the_generator_is_seeded_and_covers_its_ranges():
    table = generated_surfaces(40, seed=1)
    assert [g.family for g in table[:4]] == list(FAMILIES)
    assert generated_surfaces(40, seed=1) == table and generated_surfaces(41, seed=1)[:40] == table
    for g in table:
        assert RMS_RANGE[0] <= g.height <= RMS_RANGE[1] and PIXEL_RANGE[0] <= g.pixel <= PIXEL_RANGE[1]
        assert LENGTH_RANGE[0] <= g.length <= LENGTH_RANGE[1] and TIP_RANGE[0] <= g.tip_radius <= TIP_RANGE[1]
    # valleys narrower and wider than the tip both occur
    assert any(g.length < g.tip_radius for g in table) and any(g.length > 2 * g.tip_radius for g in table)


def test_the_plan_is_seeded_and_keeps_every_slide_on_its_scan():
    def plan(seed):
        rng = np.random.default_rng(seed)
        return [r for g in generated_surfaces(12, seed) for r in
                plan_runs(g.name, rng, g.tip_radius, GENERATED_PIXELS * g.pixel, 4, 2)]

    runs = plan(3)
    assert plan(3) == runs and plan(4) != runs
    assert {r["motion"] for r in runs if r["kind"] == "slow"} == set(SLOW_MOTIONS)
    assert len({round(r["heading_deg"]) for r in runs}) > len(runs) // 2  # several directions
    assert {r["rate_hz"] for r in runs if r["kind"] == "slow"} == {1000.0, 5000.0, 10000.0}
    for r in runs:  # the hand's set point of a 1000 nm/s slide stays within the room (1 mm -> 10 nm)
        path = _trajectory("slide-1000", 1e-5, math.radians(r["heading_deg"]), r["room_m"])
        xy = np.array([path(t)[:2] for t in np.linspace(0.0, 3.0, 301)]) * 1e-5
        assert np.linalg.norm(xy, axis=1).max() <= r["room_m"] * (1 + 1e-12)


def test_a_scan_narrower_than_the_tip_gets_only_presses_and_taps():
    runs = plan_runs("stm", np.random.default_rng(0), 20e-9, 4e-9, 4, 6)  # a 4 nm scan, a 20 nm tip
    assert {r["motion"] for r in runs} == {"press", "tap"} and all(r["room_m"] < 0 for r in runs)


def test_a_long_slide_folds_back_and_forth_within_its_room():
    s = np.linspace(0.0, 10.0, 1001)
    f = np.array([_fold(x, 2.0) for x in s])
    assert np.abs(f).max() == pytest.approx(2.0) and f.min() == pytest.approx(-2.0)
    np.testing.assert_allclose(f[s <= 2.0], s[s <= 2.0])          # unchanged while it fits
    assert np.abs(np.diff(f)).max() <= 0.01 + 1e-12                 # continuous, at the same speed
    assert _fold(6.0, 2.0) == pytest.approx(-2.0) and _fold(8.0, 2.0) == pytest.approx(0.0)


@pytest.mark.parametrize("g", SAMPLE, ids=[g.family for g in SAMPLE])
def test_a_still_or_slow_tip_meets_the_family_criteria_on_a_generated_surface(g):
    rng = np.random.default_rng(g.seed)
    run = plan_runs(g.name, rng, g.tip_radius, GENERATED_PIXELS * g.pixel, 1, 0)[0]
    r = judge_run(run, g.surface(), g.tip_radius)
    assert r["in_contact"], r
    assert max(r["high_frequency_over_normal"]) <= 0.02 and not any(r["reversals"]), r
    assert r["energy_ok"], r
    assert not r["rest_error"] > 0.01, r
    assert r["ok"], r


@pytest.mark.parametrize("g", SAMPLE, ids=[g.family for g in SAMPLE])
def test_a_still_tip_rests_on_the_scaled_force(g):
    r = judge_run({"surface": g.name, "kind": "slow", "motion": "press", "source": "simulated", "rate_hz": 1000.0,
                   "heading_deg": 0.0, "room_m": math.inf}, g.surface(), g.tip_radius)
    assert r["rest_error"] <= 0.01 and r["ok"], r


@pytest.mark.parametrize("g", SAMPLE[:2], ids=[g.family for g in SAMPLE[:2]])
def test_a_faster_motion_converges_in_the_loop_rate(g):
    r = rate_convergence(g.surface(), "circle-100", seconds=1.5, tip_radius=g.tip_radius)
    assert r["energy_ok"], (g.name, r)
    assert r["rate_error"] <= RATE_TOLERANCE, (g.name, r)
    assert np.isfinite(r["min_energy_J"]).all()


def test_the_rate_difference_keeps_texture_and_counts_what_the_loop_adds():
    """The metric itself: a 20 Hz texture sampled at 1 kHz is the 10 kHz force (0 %); a tick-to-tick
    zig-zag of 2 % of the force added by the 1 kHz loop counts in full (6 % fails) (the 10 kHz record is
    low-passed below 500 Hz, the 1 kHz one is not); a contact made one tick later at 1 kHz (a
    2 Hz tap) is timing, left out for 5 ms (4.3 % without that, the hold's own lag 8 %)."""
    t = np.arange(20000) * 1e-4
    f = np.column_stack([2e-3 * np.sin(2 * np.pi * 20 * t), 0 * t, 0.02 + 0 * t])
    assert rate_difference(f[::10], f)[0] < 1e-3
    buzz = f[::10].copy()
    buzz[:, 0] += 4e-4 * (-1.0) ** np.arange(2000)
    assert rate_difference(buzz, f)[0] == pytest.approx(0.02, rel=0.05)
    buzz[:, 0] += 8e-4 * (-1.0) ** np.arange(2000)
    assert rate_difference(buzz, f)[0] > RATE_TOLERANCE
    tap = np.column_stack([0 * t, 0 * t, np.where(t % 0.5 > 0.2, 0.02, 0.0)])
    late = np.column_stack([0 * t[::10], 0 * t[::10], np.where((t[::10] - 1e-3) % 0.5 > 0.2, 0.02, 0.0)])
    assert rate_difference(late, tap)[0] > 0.04  # 4.3 %: most of the tolerance for one tick of timing
    assert rate_difference(late, tap, contact=(late[:, 2] > 0, tap[:, 2] > 0))[0] < 0.01


#: from ``bench/feel.py --families 12 --runs 1 1 --quick --seed 5``: a Gaussian surface of 12.8 nm rms and
#: 6.3 nm correlation length under a 12 nm tip (valleys narrower than the tip)
NARROW = generated_surfaces(12, seed=5)[4]


def test_the_tip_starts_clear_of_the_asperities_beside_it():
    """A scenario's tip starts 2 nm above where it first touches, not above the height under its
    centre: on a rough scan the latter put it deep into the asperities beside it, and the loop
    started violently (the slide below: 283 % above 100 Hz, 7158 reversals, -6242 E0; judged
    clean once started clear)."""
    from arsurf.spline.surface import BSplineSurface

    x = np.linspace(0.0, 100e-9, 101)
    bump = 5e-9 * np.exp(-0.5 * ((x[:, None] - 60e-9) ** 2 + (x[None, :] - 50e-9) ** 2) / (2e-9) ** 2)
    s = BSplineSurface.from_heights(bump, (0.0, 100e-9), (0.0, 100e-9))  # heights[i_x, i_y]
    r = 20e-9  # the bump 10 nm beside the centre (50, 50) nm: the sphere rests on it, not on the flat
    top = float(s.evaluate(60e-9, 50e-9)[2])  # the fitted bump's top (the fit rounds the 5 nm peak)
    assert top > 4e-9
    assert clearance_height(s, 50e-9, 50e-9, r) == pytest.approx(top + math.sqrt(r * r - (10e-9) ** 2), abs=0.05e-9)
    assert clearance_height(s, 20e-9, 50e-9, r) == pytest.approx(r, abs=1e-12)  # out of its reach: the flat


def test_a_slow_slide_in_valleys_narrower_than_the_tip_meets_the_family_criteria():
    g = NARROW
    assert g.family == "gaussian" and g.length < g.tip_radius
    run = {"surface": g.name, "kind": "slow", "motion": "slide-1", "source": "blended", "rate_hz": 5000.0,
           "heading_deg": 200.0, "room_m": 0.5 * GENERATED_PIXELS * g.pixel - g.tip_radius - 2e-9}
    r = judge_run(run, g.surface(), g.tip_radius)
    assert r["in_contact"], r
    assert max(r["high_frequency_over_normal"]) <= 0.02 and not any(r["reversals"]), r
    assert r["energy_ok"] and r["ok"], r


#: from the same sample: a power-law surface of 9.6 nm rms and 17 nm correlation length under a 5.6 nm tip
STEEP = generated_surfaces(12, seed=5)[9]


# with the single-contact model this still press meets the criteria; the unmerged multi-contact model
# (branch h-multi2) made a contact appear deep under the tip here (5 -> 58 mN in one tick): this test guards it
def test_a_still_tip_on_a_steep_power_law_surface_meets_the_family_criteria():
    g = STEEP
    assert g.family == "power-law"
    run = {"surface": g.name, "kind": "slow", "motion": "press", "source": "simulated", "rate_hz": 1000.0,
           "heading_deg": 0.0, "room_m": math.inf}
    r = judge_run(run, g.surface(), g.tip_radius)
    assert max(r["high_frequency_over_normal"]) <= 0.02 and not any(r["reversals"]), r
    assert r["energy_ok"] and r["ok"], r
