"""The feel judged over generated families of surfaces (issue 27 §3), a seeded CI-size sample of
``bench/feel.py --families``: on each generated surface (random rough of a Gaussian or power-law
spectrum, step, ridge, with its own tip radius) the default loop a user gets - the virtual device,
virtual coupling and passivity on - must keep a still or slowly sliding tip free of buzz (content
above 100 Hz <= 2 % of the mean normal force per axis after 1 s, no tick-to-tick reversal above
1 % of the peak, energy >= -E0, at rest K_f F within 1 %) and give a faster motion a force that
converges in the loop rate."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from arsurf.feel_scenarios import (FAMILIES, LENGTH_RANGE, PIXEL_RANGE, RATE_TOLERANCE, RMS_RANGE, SLOW_MOTIONS,
                                   TIP_RANGE, GENERATED_PIXELS, _fold, _trajectory, clearance_height,
                                   GeneratedSurface, generated_surfaces, judge_run,
                                   plan_runs, rate_convergence, rate_difference)
from support.benches import SLIDE_KEY, run_on_row

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
    r = rate_convergence(g.surface(), "circle-100", seconds=1.5, tip_radius=g.tip_radius, records=True)
    assert r["energy_ok"], (g.name, r)
    assert r["rate_error"] <= RATE_TOLERANCE, (g.name, r)
    assert np.isfinite(r["min_energy_J"]).all()
    # the same records with a loop artefact injected into the 1 kHz one fail: a limit cycle of 7 % rms
    # of the force at 60 Hz (what a rest limit cycle or a coupling too stiff for 1 kHz would add)
    slow, fast = r["runs"]
    rms = float(np.sqrt(np.mean(np.sum(fast.force[10000:] ** 2, axis=1))))
    t = np.arange(slow.force.shape[0]) * 1e-3
    cycle = slow.force + 0.1 * rms * np.outer(np.sin(2 * np.pi * 60 * t), slow.force[-1] / np.linalg.norm(slow.force[-1]))
    bad = rate_difference(cycle, fast.force, contact=(slow.contact, fast.contact), probe=(slow.probe, fast.probe))[0]
    assert bad > RATE_TOLERANCE, (g.name, bad)


def test_the_rate_difference_keeps_texture_and_counts_what_the_loop_adds():
    """The metric itself: a 20 Hz texture sampled at 1 kHz is the 10 kHz force (0 %); a tick-to-tick
    zig-zag of 2 % of the force added by the 1 kHz loop counts in full (6 % fails); a contact made one
    tick later at 1 kHz (a 2 Hz tap) is timing, left out for 5 ms (4.3 % without that)."""
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
    assert rate_difference(late, tap)[0] > 0.04  # most of the tolerance for one tick of timing
    assert rate_difference(late, tap, contact=(late[:, 2] > 0, tap[:, 2] > 0))[0] < 0.01


def _slide_over_texture(wavelength, speed=1e-6, seconds=2.0):
    """A tip sliding at ``speed`` m/s over a sinusoidal texture of ``wavelength`` m: the 10 kHz
    probe (m) and force (N), and the 1 kHz probe half a tick behind (the hold's lag) with the force
    the same texture gives there (what a correct 1 kHz loop renders)."""
    t = np.arange(int(seconds * 1e4)) * 1e-4

    def force(x):
        return np.column_stack([3e-3 * np.sin(2 * np.pi * x / wavelength), 0 * x, 0.02 + 2e-3 * np.cos(2 * np.pi * x / wavelength)])

    def probe(x):
        return np.column_stack([x, 0 * x, 0 * x])

    x10, x1 = speed * t, speed * (t[::10] - 0.5e-3)
    return probe(x10), force(x10), probe(x1), force(x1)


def test_a_texture_finer_than_the_1khz_loop_resolves_is_not_counted_as_a_loop_artefact():
    """A 1000 nm/s slide over a 1.4 nm texture gives 700 Hz: the 1 kHz loop samples it, folded to
    300 Hz, and so do the 10 kHz record's samples where the 1 kHz loop sampled the surface (0 %),
    half a tick of hold lag included (the probes matched along the path). The earlier reference,
    the 10 kHz record low-passed at 450 Hz, removed what the 1 kHz record folds: it failed this
    texture by construction (low_passed_error)."""
    p10, f10, p1, f1 = _slide_over_texture(1.4e-9)
    err, low = rate_difference(f1, f10, probe=(p1, p10))
    assert err < 0.005
    assert low > RATE_TOLERANCE                                    # the low-passed reference: fails texture
    assert rate_difference(f1, f10)[0] > RATE_TOLERANCE            # unmatched: the half-tick lag at 700 Hz
    # what the 1 kHz loop adds on top of that texture still counts in full: a limit cycle at 40 Hz of 7 % rms ...
    t1 = np.arange(f1.shape[0]) * 1e-3
    cycle = f1 + np.column_stack([0 * t1, 0 * t1, 2e-3 * np.sin(2 * np.pi * 40 * t1)])
    assert rate_difference(cycle, f10, probe=(p1, p10))[0] > RATE_TOLERANCE
    # ... and a tick-to-tick zig-zag of 6 % of the rms force
    zig = f1 + np.column_stack([1.3e-3 * (-1.0) ** np.arange(f1.shape[0]), 0 * t1, 0 * t1])
    assert rate_difference(zig, f10, probe=(p1, p10))[0] > RATE_TOLERANCE


def test_a_tip_in_flight_compares_its_noise_against_the_peak_not_against_itself():
    """Out of contact the device force is the free lever's reading, noise drawn anew at each rate:
    relative to its own rms two noise records differ by ~140 %; the scale is at least 1 % of the
    peak force (a 20 mN press before the flight), so they compare at ~1.2 % (of 0.2 mN), while the same
    noise over a 20 mN held force is 0.01 %, and a limit cycle of 3.5 % rms on that force still counts."""
    rng = np.random.default_rng(1)
    n = 2000
    press = np.zeros((10 * n, 3))
    press[:5000, 2] = 0.02                                          # pressed for 0.5 s, then in flight
    noise10, noise1 = rng.normal(0.0, 1e-6, (10 * n, 3)), rng.normal(0.0, 1e-6, (n, 3))
    assert rate_difference(noise1, noise10)[0] > 1.0                 # noise against noise, no floor
    assert rate_difference(noise1, press + noise10)[0] < 0.02        # the floor: 1 % of the 20 mN peak
    held = np.zeros((10 * n, 3))
    held[:, 2] = 0.02
    assert rate_difference(held[::10] + noise1, held + noise10)[0] < 0.01
    t1 = np.arange(n) * 1e-3
    cycle = held[::10] + np.column_stack([0 * t1, 0 * t1, 1e-3 * np.sin(2 * np.pi * 30 * t1)])
    assert rate_difference(cycle, held)[0] > 0.03


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


def test_a_stroke_starts_where_it_comes_down_not_over_the_middle():
    """A stroke comes down 150 nm before the middle of its scan: the stylus starts there, clear of
    the surface, even where the middle stands higher. (It started over the middle, at the height
    cleared for the start point: on the nanoFTIR scan, whose middle is 100 nm above that point, the
    tip began 60 nm deep, at 205 mN on the hand and -993 E0.)"""
    from arsurf.feel_scenarios import run_scenario
    from arsurf.spline.surface import BSplineSurface

    x = np.linspace(0.0, 600e-9, 121)
    ramp = np.broadcast_to((0.2 * x)[:, None], (121, 121)).copy()  # rises 20 nm per 100 nm along x
    s = BSplineSurface.from_heights(ramp, (0.0, 600e-9), (0.0, 600e-9))
    r = run_scenario(s, motion="stroke", rate=1000.0, seconds=1.5, tip_radius=10e-9)
    assert not r.contact[0] and np.linalg.norm(r.force[0]) == 0.0, (r.contact[:3], r.force[:3])
    assert r.probe[0][0] == pytest.approx(300e-9 - 150e-9, abs=1e-9)  # 150 nm before the middle along x
    assert r.energy.min() >= -r.energy_reserve, (r.energy.min(), r.energy_reserve)


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


#: from the whole table (``bench/feel.py --families 240 --runs 4 2``, seed 0): a power-law surface of
#: 2.1 nm rms and 11 nm correlation length under a 4.6 nm tip, and one of 0.8 nm rms and 30 nm
#: correlation length under a 7.0 nm tip
VALLEY, HOLLOW = (generated_surfaces(240, seed=0)[k] for k in (9, 237))


def test_a_still_press_in_a_valley_narrower_than_the_tip_gives_the_hand_no_energy():
    """Pressed into a valley whose walls turn the contact normal within a fraction of a nanometre,
    the hand held still must not gain energy. With the force turned by a 50 Hz low-passed normal
    (a lagging direction) the hand swung across the valley at ~10 Hz and gained 6 times the
    passive store (-6.0 E0), beyond what the passivity controller could take back."""
    g = VALLEY
    run = {"surface": g.name, "kind": "slow", "motion": "press", "source": "blended", "rate_hz": 10000.0,
           "heading_deg": 3.58, "room_m": 6.66e-08}
    r = judge_run(run, g.surface(), g.tip_radius)
    assert r["energy_ok"] and r["min_energy_over_E0"] >= -1.0, r
    assert r["ok"], r


def test_a_slow_slide_through_hollows_that_fit_the_tip_does_not_buzz():
    """Where the distance to the surface is nearly the same over a patch the closest point wanders
    across it, and its normal with it: pushed along the closest point's normal a 1 nm/s slide here
    stepped the force by 15 nN of 120 (2.2 % above 100 Hz, 3 reversals); along the resultant over
    the contact's zone (arsurf.contact.zone_normal) it is smooth."""
    g = HOLLOW
    run = {"surface": g.name, "kind": "slow", "motion": "slide-1", "source": "simulated", "rate_hz": 1000.0,
           "heading_deg": 157.79, "room_m": 8.58e-08}
    r = judge_run(run, g.surface(), g.tip_radius)
    assert r["in_contact"], r
    assert max(r["high_frequency_over_normal"]) <= 0.02 and not any(r["reversals"]), r
    assert r["ok"], r


#: from the seed-1 table (``bench/feel.py --families 120 --runs 4 2 --seed 1``): a power-law surface
#: of 7.0 nm rms and 4.3 nm correlation length under a 3.4 nm tip
ROUGH_PIT = generated_surfaces(120, seed=1)[113]


def test_a_slow_slide_through_a_rough_pit_gives_the_hand_no_energy_through_friction():
    """Sliding at 1 nm/s through a patch where the 3.4 nm tip rests on some fifteen minima, the
    friction's spring was stretched by the closest point, which ran ahead of the tip and hopped
    among the minima: not a gradient, it gave the hand 11 times the passive store (-11.3 E0) with
    the passivity controller acting on 9 688 of 15 000 ticks, and 5 reversals. Stretched by the
    tip's own tangential move (arsurf.contact.friction) it gives back what the hand put in."""
    g = ROUGH_PIT
    run = {"surface": g.name, "kind": "slow", "motion": "slide-1", "source": "blended", "rate_hz": 5000.0,
           "heading_deg": 206.22, "room_m": 2.71e-08}
    r = judge_run(run, g.surface(), g.tip_radius)
    assert r["in_contact"], r
    assert r["energy_ok"] and r["min_energy_over_E0"] >= -1.1 and r["passivity_ticks"] <= 150, r
    assert max(r["high_frequency_over_normal"]) <= 0.02 and not any(r["reversals"]), r


SNAPPING = generated_surfaces(10, seed=0)[9]  # power-law, 2.1 nm rms over 11 nm, under a 4.6 nm tip


def test_a_slow_slide_that_snaps_over_asperities_reaches_the_hand_without_a_step():
    """Sliding at 10 nm/s, the hand drives the target into asperities thinner than the tip; the
    balance behind the coupling snaps over their tops, up to 2.7 nm in one tick. Rendered in one
    tick that was a step of 18.8 mN at the hand, 20 reversals and 2.9 % of the force above 100 Hz
    (the seed-0 table's run); the loop's default blend (arsurf.contact.jump_blend) spreads each
    snap over 15 ms."""
    g = SNAPPING
    run = {"surface": g.name, "kind": "slow", "motion": "slide-10", "source": "simulated", "rate_hz": 1000.0,
           "heading_deg": 15.504079884553503, "room_m": 6.663489499732051e-08}
    r = judge_run(run, g.surface(), g.tip_radius)
    assert r["in_contact"] and r["energy_ok"], r
    assert max(r["high_frequency_over_normal"]) <= 0.02 and not any(r["reversals"]), r
    assert r["largest_step_N"] <= 0.5 * r["mean_normal_N"], r  # 1.15 times it in one tick


RUNAWAY_LIFT = generated_surfaces(240, seed=0)[133]  # power-law, 6.1 nm rms over 2.0 nm, under a 10.2 nm tip


def test_a_fast_slide_off_an_asperity_gives_the_hand_no_more_than_the_passive_store():
    """The seed-0 table's 1000 nm/s measured slide on a 6.1 nm rms power-law surface of 2.0 nm
    correlation length under a 10.2 nm tip, at 1 kHz: the hand drives the tip 19.5 nm onto an
    asperity, and the coupling, released as the tip comes off it, pushed the hand out with the
    held force for four ticks, 213 times the passive store (-213 E0) before the passivity
    controller, which damped only the deficit already observed, acted. Counting the coming tick
    (arsurf.haptics.passivity) the observed energy stays above -E0."""
    from arsurf.feel_scenarios import energy_ok, run_scenario

    g = RUNAWAY_LIFT
    assert g.name == "power-law#681137310 h=6.07nm l=2.03nm px=0.628nm R=10.2nm"  # the table's surface
    run = run_scenario(g.surface(), motion="slide-1000", source="measured", rate=1000.0, seconds=2.0,
                       tip_radius=g.tip_radius, heading=math.radians(137.7104578763139), room=4.8098114288779963e-08,
                       coupling_rate=1000.0)
    assert run.contact.mean() > 0.9 and run.passivity_ticks > 0
    assert energy_ok(run) and run.score.min_energy >= -run.energy_reserve, run.score.min_energy / run.energy_reserve


#: from the seed-1 table: a power-law surface of 11.5 nm rms and 34.3 nm correlation length under a 3.75 nm tip
CAUGHT_IN_A_PIT = generated_surfaces(120, seed=1)[41]


def test_a_fast_circle_caught_in_a_pit_gives_the_same_force_at_1_and_10_khz():
    """The seed-1 table's 1000 nm/s circle, blended source: the tip is caught in a pit, where its
    balance behind the coupling jumps between the pit's walls. Each jump, taken in one 1 ms tick,
    gave a force that depended on where the tick fell: the lateral force cycled at 30 Hz, the 1 kHz
    record was 109 % of the force from the 10 kHz one, and the hand got 13 times the passive
    store (-12.9 E0). Each jump tick is now run again in 0.1 ms steps (arsurf.contact.jump_blend),
    so the 1 kHz loop meets the jump as the 10 kHz one does."""
    from arsurf.feel_scenarios import rate_convergence

    g = CAUGHT_IN_A_PIT
    assert g.name == "power-law#1943478222 h=11.5nm l=34.3nm px=0.716nm R=3.75nm"  # the table's surface
    r = rate_convergence(g.surface(), "circle-1000", source="blended", seconds=2.0, tip_radius=g.tip_radius,
                         heading=math.radians(352.1200275721489), room=6.296712274571056e-08)
    assert r["rate_error"] <= RATE_TOLERANCE and r["energy_ok"], r
    assert min(r["min_energy_over_E0"]) >= -1.0, r


#: from the seed-0 table: a power-law surface of 2.7 nm rms and 4.8 nm correlation length, 1.5 nm pixels,
#: under a 4.1 nm tip
CONTACTS_COME_AND_GO = generated_surfaces(240, seed=0)[153]


def test_a_slide_whose_contacts_come_and_go_gives_the_same_force_at_1_and_10_khz():
    """The seed-0 table's 100 nm/s slide (simulated source): contacts are found and lost as the tip
    crosses the patch. With only the jump ticks run again in 0.1 ms steps, a 1 kHz tick in which a
    contact was found took it a whole 1 ms step at once, and the 1 kHz force was 7.9 % from the
    10 kHz one (0.95 % before the jump redo, by chance); run again as well, 0.69 %."""
    from arsurf.feel_scenarios import rate_convergence

    g = CONTACTS_COME_AND_GO
    assert g.name == "power-law#1847721419 h=2.66nm l=4.77nm px=1.46nm R=4.06nm"  # the table's surface
    r = rate_convergence(g.surface(), "slide-100", source="simulated", seconds=2.0, tip_radius=g.tip_radius,
                         heading=math.radians(300.1066917261163), room=1.3454025906591605e-07)
    assert r["rate_error"] <= 0.02 and r["energy_ok"], r


#: from the seed-0 table: a power-law surface of 9.5 nm rms and 8.8 nm correlation length under a 7.0 nm tip
PRESSED_AMONG_MANY = generated_surfaces(240, seed=0)[57]


@pytest.mark.xfail(strict=True, reason="issue 27: the tip behind the coupling is placed from the target's contacts, "
                                       "not followed from where it was (docs/feel.rst)")
def test_a_slow_slide_pressed_among_a_dozen_contacts_does_not_buzz_at_1_khz():
    """The seed-0 table drew this 10 nm/s slide at 10 kHz with the measured source (7 reversals); run
    at 1 kHz with the simulated source it buzzes: pressed among 7-16 contacts, the balance behind the
    coupling moves 1-7 nm in a tick while the hand moves 0.05-0.4 nm, more hops than the blend takes
    up (33-78 reversals, 5.5-9.4 % of the force above 100 Hz, -63 to -857 E0 over this session's
    changes to the loop)."""
    g = PRESSED_AMONG_MANY
    assert g.name == "power-law#907587570 h=9.54nm l=8.81nm px=0.338nm R=7.01nm"  # the table's surface
    run = {"surface": g.name, "kind": "slow", "motion": "slide-10", "source": "simulated", "rate_hz": 1000.0,
           "heading_deg": 132.03040803394612, "room_m": 2.341060439609643e-08}
    r = judge_run(run, g.surface(), g.tip_radius)
    assert r["in_contact"], r
    assert max(r["high_frequency_over_normal"]) <= 0.02 and not any(r["reversals"]) and r["energy_ok"], r


def _bench_feel():
    """bench/feel.py as a module (a script, not a package)."""
    from support.benches import load_bench

    return load_bench("feel")


def test_the_whole_table_streams_its_rows_and_resumes_where_it_stopped(tmp_path, monkeypatch):
    """``bench/feel.py --families --out``: every judged run is one JSON line (no NaN, units in the
    keys), a line cut short by a stopped run is skipped, and a second call judges only the runs not
    yet in the file; the summary counts each run once per family, motion and rate."""
    feel = _bench_feel()
    runs, _ = feel.plan_table(4, 5, real=False, slow_runs=1, fast_runs=1)
    assert len(runs) == 8 and len({r["key"] for r in runs}) == 8
    judged = []

    def judge(run):  # the orchestration only: each planned run "judged" as passing, with its NaNs
        judged.append(run["key"])
        keep = {k: v for k, v in run.items() if k not in ("generated", "scan")}
        extra = ({"rate_error": 0.01, "low_passed_error": 0.02, "min_energy_over_E0": [-0.5, math.nan]}
                 if run["kind"] == "fast" else
                 {"high_frequency_over_normal": [0.0, 0.0, 0.0], "reversals": [0, 0, 0], "rest_error": math.nan,
                  "min_energy_over_E0": -0.5})
        return feel._jsonable({**keep, **extra, "energy_ok": True, "ok": run["key"] != runs[0]["key"], "wall_s": 0.1})

    monkeypatch.setattr(feel, "judge_planned", judge)
    out = tmp_path / "rows.jsonl"
    out.write_text(json.dumps(judge(runs[2])) + "\n" + '{"key": "cut sh')  # one judged, one cut short
    judged.clear()
    s = feel.families(4, 5, real=False, slow_runs=1, fast_runs=1, out=str(out))["summary"]
    assert judged == [r["key"] for r in runs if r["key"] != runs[2]["key"]]
    rows = feel.read_rows(out)
    assert sorted(r["key"] for r in rows) == sorted(r["key"] for r in runs)
    assert "NaN" not in out.read_text() and all("tip_radius_m" in r and "room_m" in r for r in rows)
    assert s["runs"] == 8 and s["pass"] == 7 and s["by_family"] == {"gaussian": "1/2", "power-law": "2/2",
                                                                    "ridge": "2/2", "step": "2/2"}
    judged.clear()
    assert feel.families(4, 5, real=False, slow_runs=1, fast_runs=1, out=str(out))["summary"]["runs_judged_now"] == 0
    assert judged == []


def test_two_tables_compare_by_the_runs_they_pass_differently_and_by_their_measures(tmp_path):
    """``bench/feel.py --compare OLD NEW``: the runs gained and lost between two tables of one plan
    (only the runs both hold), and each table's measures beyond its pass count: the rate pairs' mean
    and median error and how many exceed the tolerance, the slow runs' content above 100 Hz,
    reversals, the runs failing the energy and the energy beyond -E0 summed."""
    import subprocess
    import sys
    from pathlib import Path

    feel = _bench_feel()

    def fast(key, err, energy):
        return {"key": key, "kind": "fast", "surface": key, "motion": "slide-100", "heading_deg": 0.0,
                "source": "simulated", "rate_error": err, "low_passed_error": err, "min_energy_over_E0": [energy, None],
                "energy_ok": energy >= -1.2, "ok": err <= RATE_TOLERANCE and energy >= -1.2}  # -1.2: as if a tolerance

    def slow(key, hf, rev):
        return {"key": key, "kind": "slow", "surface": key, "motion": "slide-10", "heading_deg": 0.0,
                "source": "measured", "rate_hz": 1000.0, "high_frequency_over_normal": [hf, 0.0, 0.0],
                "reversals": [rev, 0, 0], "min_energy_over_E0": -0.5, "rest_error": None, "ok": hf <= 0.02 and not rev}

    old = [fast("a", 0.20, -0.5), fast("b", 0.01, -3.0), slow("c", 0.03, 4), slow("d", 0.001, 0), fast("x", 0.0, 0.0)]
    new = [fast("a", 0.02, -0.5), fast("b", 0.01, -1.1), slow("c", 0.01, 0), slow("d", 0.001, 2)]
    c = feel.compare(old, new)
    assert c["runs_compared"] == 4
    assert [g.split(" ")[0] for g in c["gained"]] == ["a", "b", "c"] and [g.split(" ")[0] for g in c["lost"]] == ["d"]
    assert c["old"]["pass"] == 1 and c["new"]["pass"] == 3  # "x", in the old table only, is not compared
    assert c["old"]["rate_error_mean_percent"] == pytest.approx(10.5) and c["new"]["rate_error_mean_percent"] == pytest.approx(1.5)
    assert c["old"]["rate_pairs_beyond_tolerance"] == 1 and c["new"]["rate_pairs_beyond_tolerance"] == 0
    assert (c["old"]["reversals_summed"], c["new"]["reversals_summed"]) == (4, 2)
    assert (c["old"]["slow_runs_beyond_buzz_limit"], c["new"]["slow_runs_beyond_buzz_limit"]) == (1, 0)
    assert c["old"]["energy_beyond_minus_E0_summed_over_E0"] == pytest.approx(-2.0)
    assert c["new"]["energy_beyond_minus_E0_summed_over_E0"] == pytest.approx(-0.1)
    assert (c["old"]["runs_failing_energy"], c["new"]["runs_failing_energy"]) == (1, 0)  # below -E0, within tolerance
    assert (c["old"]["runs_below_minus_E0"], c["new"]["runs_below_minus_E0"]) == (1, 1)
    files = []
    for name, rows in (("old", old), ("new", new)):
        files.append(tmp_path / f"{name}.jsonl")
        files[-1].write_text("".join(json.dumps(r) + "\n" for r in rows))
    script = Path(__file__).resolve().parents[2] / "bench" / "feel.py"
    done = subprocess.run([sys.executable, str(script), "--compare", *map(str, files)], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["families"]["compare"] == json.loads(json.dumps(c))
    done = subprocess.run([sys.executable, str(script), "--compare", str(files[0]), str(tmp_path / "none.jsonl")],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "no judged runs" in done.stderr


def test_the_pair_bench_finds_where_two_rates_part_and_reruns_a_pair_as_the_table_judged_it(tmp_path):
    """``bench/feel_pairs.py``: two records that differ in one 100 ms window put all of their squared
    difference there, and the tips' separation is read where the 1 kHz probe passes; a pair of a
    table is run again exactly as the table judged it (the same rate error), and once with the jump
    blend off; a key the plan does not hold is refused in one line."""
    from types import SimpleNamespace

    from support.benches import load_bench

    pairs = load_bench("feel_pairs")
    t = np.arange(30000) * 1e-4  # 3 s at 10 kHz
    probe = np.column_stack([100e-9 * t, 0 * t, 0 * t])  # a slide at 100 nm/s
    force = np.column_stack([1e-3 * np.sin(2 * np.pi * 5 * t), 0 * t, 0.02 + 0 * t])
    fast = SimpleNamespace(force=force, probe=probe, tip=probe + [0.0, 0.0, 3e-9])
    slow = SimpleNamespace(force=force[::10].copy(), probe=probe[::10], tip=fast.tip[::10].copy())
    same = pairs.parting(slow, fast)
    assert same["worst_window_share"] == 0.0 and same["tips_apart_max_m"] == pytest.approx(0.0, abs=1e-18)
    slow.force[2000:2100, 0] += 1e-3  # 2.0-2.1 s: one event
    slow.tip[2000:2100, 2] += 0.5e-9
    event = pairs.parting(slow, fast)
    assert event["worst_window_share"] == pytest.approx(1.0) and event["tips_apart_max_m"] == pytest.approx(0.5e-9)
    assert event["tips_apart_median_window_m"] == pytest.approx(0.0, abs=1e-18)

    key = SLIDE_KEY
    done = run_on_row("feel_pairs.py", tmp_path / "rows.jsonl", {"key": key, "kind": "fast", "ok": False})
    assert done.returncode == 0, done.stderr
    (pair,) = json.loads(done.stdout)["pairs"]
    default, off = pair["settings"]
    run = next(r for r in _bench_feel().plan_table(4, 5, real=False, slow_runs=1, fast_runs=1)[0] if r["key"] == key)
    judged = judge_run({k: v for k, v in run.items() if k != "generated"}, GeneratedSurface(**run["generated"]).surface(),
                       run["tip_radius_m"])
    assert default["rate_error"] == judged["rate_error"] and default["jump_blend_s"] == "default"
    assert off["jump_blend_s"] == 0.0 and off["rate_error"] != default["rate_error"]  # the blend acts on this slide
    for setting in (default, off):
        assert 0.0 <= setting["worst_window_share"] <= 1.0 and 0.0 <= setting["tips_apart_max_m"] < 1e-9
    done = run_on_row("feel_pairs.py", tmp_path / "rows.jsonl", {"key": "5:9:9:none", "kind": "fast", "ok": False})
    assert done.returncode == 1 and done.stderr.count("\n") == 1 and "not in the plan" in done.stderr


def test_the_field_bench_reads_a_single_contact_as_a_gradient_behind_the_coupling(tmp_path):
    """``bench/feel_field.py``: a failing run of a table repeated and its force field read. A press on
    a step (one smooth contact) without friction meets a gradient (no skew part) that is stiffer
    than nothing and, the contact in series with the coupling, softer than the coupling; a key the
    plan does not hold is refused in one line."""
    key = "5:2:0:step#606100190 h=18.2nm l=83nm px=7.98nm R=4.25nm"  # plan_table(4, 5, runs 1 1): a press
    done = run_on_row("feel_field.py", tmp_path / "rows.jsonl", {"key": key, "kind": "slow", "ok": False})
    assert done.returncode == 0, done.stderr
    (run,) = json.loads(done.stdout)["runs"]
    assert run["key"] == key and [v["friction"] for v in run["runs"]] == ["preset", 0.0]
    for field in run["runs"][1]["fields"]:
        assert len(field["contacts"]) == 1 and field["skew_over_k_c"] <= 1e-3
        assert 0.05 < max(field["stiffness_over_k_c"]) < 1.0
    done = run_on_row("feel_field.py", tmp_path / "rows.jsonl", {"key": "5:9:9:none", "kind": "slow", "ok": False})
    assert done.returncode == 1 and done.stderr.count("\n") == 1 and "not in the plan" in done.stderr


def test_with_the_zone_energy_the_tip_starts_clear_of_its_cone_too():
    """The zone energy's tip is its sphere on a 15 degree cone (arsurf.contact.zone_energy): a
    60 nm pillar 26 nm beside the middle is out of the 20 nm sphere's reach but not of its cone.
    Started where the sphere is 2 nm clear, the hand was pushed from the first tick (5.5 mN) and
    gained 1.45 times the passive store; the scenario raises its start until the cone is clear."""
    from arsurf.feel_scenarios import run_scenario
    from arsurf.spline.surface import BSplineSurface

    x = np.linspace(0.0, 120e-9, 121)
    xx, yy = np.meshgrid(x, x, indexing="ij")
    pillar = 60e-9 * np.exp(-0.5 * ((xx - 86e-9) ** 2 + (yy - 60e-9) ** 2) / (2.5e-9) ** 2)
    s = BSplineSurface.from_heights(pillar, (0.0, 120e-9), (0.0, 120e-9))
    r = run_scenario(s, motion="press", rate=1000.0, seconds=1.2, tip_radius=20e-9, zone_energy=True)
    assert not r.force[0].any()
    assert r.score.min_energy >= -0.1 * r.energy_reserve
