"""The feel judged over generated families of surfaces (issue 27 §3), a seeded CI-size sample of
``bench/feel.py --families``: on each generated surface (random rough of a Gaussian or power-law
spectrum, step, ridge, with its own tip radius) the default loop a user gets - the virtual device,
virtual coupling and passivity on - must keep a still or slowly sliding tip free of buzz (content
above 100 Hz <= 2 % of the mean normal force per axis after 1 s, no tick-to-tick reversal above
1 % of the peak, energy >= -E0) and give a faster slide a force that converges in the loop rate."""
from __future__ import annotations

import numpy as np
import pytest

from arsurf.feel_scenarios import (FAMILIES, LENGTH_RANGE, PIXEL_RANGE, RATE_TOLERANCE, RMS_RANGE, TIP_RANGE,
                                   generated_surfaces, rate_convergence, run_scenario)

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


@pytest.mark.parametrize("g", SAMPLE, ids=[g.family for g in SAMPLE])
def test_a_still_tip_does_not_buzz_on_a_generated_surface(g):
    run = run_scenario(g.surface(), motion="press", source="simulated", rate=1000.0, seconds=2.0,
                       tip_radius=g.tip_radius)
    s = run.score
    assert run.contact[-500:].all(), g.name
    assert (s.high_frequency <= 0.02).all() and not s.reversals.any(), (g.name, s.summary())
    assert not s.buzzes, (g.name, s.summary())


@pytest.mark.xfail(strict=True, reason="issue 27 §3 not met yet: a 100 nm/s circle differs by 22-23 % rms between "
                   "1 kHz and 10 kHz (tolerance 15 %); the still-tip criteria hold")
@pytest.mark.parametrize("g", SAMPLE[:2], ids=[g.family for g in SAMPLE[:2]])
def test_a_faster_motion_converges_in_the_loop_rate(g):
    r = rate_convergence(g.surface(), "circle-100", seconds=1.5, tip_radius=g.tip_radius)
    assert r["energy_ok"], (g.name, r)
    assert r["rate_error"] <= RATE_TOLERANCE, (g.name, r)
    assert np.isfinite(r["min_energy_J"]).all()
