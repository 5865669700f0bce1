"""Haptic feel: the scores, the passivity controller, the coupling, and the buzz scenarios on real scans."""
import math

import numpy as np
import pytest

from arsurf.errors import HapticsError
from arsurf.haptics.feel import score_force
from arsurf.haptics.passivity import PassivityController
from arsurf.haptics.virtual_device import HandModel, VirtualDevice

DT = 1e-3


def _steady(n=3000, normal=0.02):
    f = np.zeros((n, 3))
    f[:, 2] = normal
    return f


# --- the scores ---------------------------------------------------------------------------------
def test_a_known_buzz_is_measured_exactly_and_a_steady_push_is_smooth():
    assert not score_force(_steady(), DT).buzzes
    f = _steady()
    t = np.arange(f.shape[0]) * DT
    f[:, 0] = 0.002 * np.sin(2 * np.pi * 300 * t)  # 2 mN at 300 Hz on a 20 mN push: rms/N = 0.0707
    s = score_force(f, DT)
    assert s.high_frequency[0] == pytest.approx(0.002 / math.sqrt(2) / 0.02, rel=1e-5)
    assert s.high_frequency[1] == 0.0 and s.buzzes
    f[:, 0] = 0.002 * np.sin(2 * np.pi * 20 * t)  # the same swing at 20 Hz is a motion, not a buzz
    assert score_force(f, DT).high_frequency[0] < 1e-3  # window leakage only


def test_reversals_count_tick_to_tick_zigzags_above_one_percent_of_the_peak():
    f = _steady(normal=0.01)
    f[1000:1101, 1] = 0.2e-3 * (-1.0) ** np.arange(101)       # legs of 0.4 mN > 1 % of 10.2 mN
    assert score_force(f, DT).reversals.tolist() == [0, 100, 0]
    f[1000:1101, 1] = 0.04e-3 * (-1.0) ** np.arange(101)      # legs of 0.08 mN < 0.1 mN
    assert score_force(f, DT).reversals.tolist() == [0, 0, 0]


def test_settling_time_of_a_first_order_response_is_tau_ln_20():
    tau = 0.05
    t = np.arange(3000) * DT
    onset = 200
    f = np.zeros((3000, 3))
    f[onset:, 2] = 0.02 * (1.0 - np.exp(-(t[onset:] - t[onset]) / tau))
    contact = t >= t[onset]
    s = score_force(f, DT, contact=contact)
    assert s.settle_time == pytest.approx(tau * math.log(20.0), abs=DT)


def test_energy_below_zero_and_bad_records():
    e = np.full(3000, 1e-4)
    assert not score_force(_steady(), DT, energy=e).buzzes
    e[2000] = -2e-6  # below -1 % of the largest |E|
    assert score_force(_steady(), DT, energy=e).buzzes
    with pytest.raises(HapticsError, match=r"\(n, 3\)"):
        score_force(np.zeros((10, 2)), DT)
    bad = _steady()
    bad[5, 0] = np.nan
    with pytest.raises(HapticsError, match="non-finite"):
        score_force(bad, DT)
    with pytest.raises(HapticsError, match="0.1 s"):
        score_force(_steady(1050), DT)


# --- passivity ----------------------------------------------------------------------------------
def _wall(stiffness, enabled):
    """A hand pushing 2 mm into a virtual wall F = -K z (z < 0) on the default virtual device."""
    dev = VirtualDevice(dt=DT, hand=HandModel(lambda t: [0.0, 0.0, -2e-3 * min(t / 0.2, 1.0)])).open()
    pc = PassivityController(DT, max_damping=float(dev.info.max_damping.min()), enabled=enabled)
    energy, force = np.empty(2000), np.empty(2000)
    for k in range(2000):
        s = dev.read_state()
        f = np.array([0.0, 0.0, -stiffness * s.position[2] if s.position[2] < 0 else 0.0])
        pc.step(s.position, s.velocity, f)
        dev.command_force(f)
        pc.applied(f)
        energy[k], force[k] = pc.energy, f[2]
    dev.close()
    return energy, force


def test_the_passivity_controller_keeps_a_too_stiff_wall_passive_and_at_rest():
    """K = 5 kN/m is 75 times the 2 b / T = 67 N/m a 1 kHz loop renders passively on this device
    (Colgate & Schenkel 1997): alone it creates energy and chatters; with the controller the
    observed energy stays above -1 uJ and the hand comes to rest on the wall."""
    e_off, f_off = _wall(5000.0, enabled=False)
    e_on, f_on = _wall(5000.0, enabled=True)
    assert e_off.min() < -1e-3 and np.ptp(f_off[1000:]) > 0.5           # generated energy, a limit cycle
    assert e_on.min() > -1e-6 and np.ptp(f_on[1000:]) < 1e-9             # passive, still
    assert f_on[-1] == pytest.approx(2e-3 * 100 / 3 * 5000 / (5000 + 100 / 3), rel=1e-3)  # rest: hand spring = wall


# --- the loop on real scans (issue #13's buzz scenarios) ---------------------------------------
@pytest.fixture(scope="module")
def spm_surface():
    from tests.support.real_scans import real_scan_path

    from arsurf.feel_scenarios import prepared_surface

    return prepared_surface(real_scan_path("sample_0.spm"))[1]


@pytest.mark.parametrize("source", ["simulated", "measured"])
def test_pressing_still_on_a_real_scan_is_steady_and_renders_the_scaled_tip_force(spm_surface, source):
    from arsurf.feel_scenarios import run_scenario

    run = run_scenario(spm_surface, motion="press", source=source)
    assert not run.score.buzzes, run.score.summary()
    assert run.transparency == pytest.approx(1.0, abs=0.01)  # steady state: K_f F within 1 %


@pytest.mark.parametrize("motion", ["slide-1", "slide-10"])
def test_sliding_slowly_with_the_measured_source_does_not_buzz(spm_surface, motion):
    """Before the friction proxy: 7 % of the normal force above 100 Hz and 1200 reversals in 3000
    ticks at 10 nm/s (the friction direction, from a finite-difference velocity at the threshold,
    flipped the decoupling every few ticks)."""
    from arsurf.feel_scenarios import run_scenario

    run = run_scenario(spm_surface, motion=motion, source="measured", signal_noise=0.0)
    assert not run.score.buzzes, run.score.summary()
    assert (run.score.high_frequency <= 0.02).all()


def test_a_steady_slide_carries_mu_k_times_the_normal_force():
    from arsurf.feel_scenarios import run_scenario
    from arsurf.spline.surface import BSplineSurface

    flat = BSplineSurface.from_heights(np.zeros((128, 128)), (0.0, 127 * 4e-9), (0.0, 127 * 4e-9))
    run = run_scenario(flat, motion="slide-100", source="simulated", friction=0.2)
    f = run.force[-1000:].mean(axis=0)
    assert not run.score.buzzes
    assert -f[0] / f[2] == pytest.approx(0.2, rel=0.02)


def test_the_coupling_balances_the_contact_and_caps_the_stiffness():
    """Behind a coupling k the tip sits where P(delta) = k (delta_t - delta), on the target's normal
    line, and the load grows with the target depth at the series stiffness, never more than k."""
    from arsurf.assembly import LEVER, make_model
    from arsurf.spline.surface import BSplineSurface

    flat = BSplineSurface.from_heights(np.zeros((40, 40)), (0.0, 39 * 4e-9), (0.0, 39 * 4e-9))
    k = 50.0
    m = make_model(flat, tip_radius=20e-9, effective_modulus=10e9, work_of_adhesion=0.1, cantilever=LEVER,
                   coupling_stiffness=k, deform=False)
    bare = make_model(flat.copy(), tip_radius=20e-9, effective_modulus=10e9, work_of_adhesion=0.1,
                      cantilever=LEVER, deform=False)
    loads = []
    for target in np.linspace(1e-9, 6e-9, 11):
        c = (78e-9, 78e-9, 20e-9 - target)
        t = m.step(c)
        assert t.coupled and t.load > 0
        assert t.load == pytest.approx(k * (target - t.depth), rel=1e-6)
        np.testing.assert_allclose(t.tip, [78e-9, 78e-9, 20e-9 - t.depth], rtol=0, atol=1e-18)
        assert t.load < bare.step(c).load
        loads.append(t.load)
    slope = np.diff(loads) / 0.5e-9
    assert (slope > 0).all() and (slope <= k).all()


# --- taps, the start-up ramp and the adhesive well ------------------------------------------------
def test_tapping_a_real_scan_is_passive_and_does_not_buzz(spm_surface):
    """Tapping twice a second (make and break contact, adhesive snap-in and pull-off) at 1 kHz.
    Before: the start-up ramp grew while the first tap loaded the contact (-0.2 uJ created)."""
    from arsurf.feel_scenarios import run_scenario

    run = run_scenario(spm_surface, motion="tap", source="simulated", rate=1000.0)
    assert run.contact.sum() > 0.4 * run.contact.size and (~run.contact).sum() > 0.3 * run.contact.size
    assert not run.score.buzzes, run.score.summary()


def test_the_start_ramp_engages_in_free_space_at_once_and_ramps_a_loaded_start():
    from arsurf.haptics.safety import SafetyLayer

    s = SafetyLayer(max_force=7.9, dt=DT, ramp_time=0.1, max_rate=1000.0)
    s.step([0.0, 0.0, 0.0], now=0.0)
    assert s.gain == 1.0  # nothing to jolt: engaged
    s.reset()
    out = [float(s.step([0.0, 0.0, 5.0], now=k * DT)[2]) for k in range(3)]
    assert out == pytest.approx([0.05, 0.1, 0.15]) and s.gain < 1.0  # a loaded start still ramps


def test_the_passivity_controller_spends_the_adhesive_reserve_before_damping():
    """E >= -E0 is passive for an environment that holds E0 (the adhesive well): no damping until
    the observed energy goes below it, then just the damping that restores -E0 in one tick."""
    pc = PassivityController(DT, max_damping=1e9, reserve=2e-3)
    f = np.array([1.0, 0.0, 0.0])
    pc.step([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], f)
    pc.applied(f)
    assert pc.step([1e-3, 0.0, 0.0], [1.0, 0.0, 0.0], f) == 0 and f[0] == 1.0  # E = -1 mJ > -2 mJ
    pc.applied(f)
    flag = pc.step([3e-3, 0.0, 0.0], [2.0, 0.0, 0.0], f)                          # E = -3 mJ
    assert flag and pc.damping == pytest.approx(1e-3 / (DT * 4.0))
    assert f[0] == pytest.approx(1.0 - pc.damping * 2.0)
    with pytest.raises(HapticsError, match="reserve"):
        PassivityController(DT, reserve=-1.0)


def test_the_adhesion_energy_bounds_the_work_of_the_adhesive_branch():
    """E0 bounds the work the tensile part of the MD curve gives back, integrated numerically."""
    from arsurf.assembly import LEVER, make_model
    from arsurf.spline.surface import BSplineSurface

    flat = BSplineSurface.from_heights(np.zeros((20, 20)), (0.0, 19e-9), (0.0, 19e-9))
    m = make_model(flat, tip_radius=20e-9, effective_modulus=10e9, work_of_adhesion=0.1, cantilever=LEVER, deform=False)
    md = m.contact
    d = np.linspace(md.jump_out_depth(), float(md.depth(0.0)), 2001)
    p = np.asarray(md.contact_state(d).load)
    work = -np.trapezoid(np.minimum(p, 0.0), d)
    assert 0.0 < work <= m.adhesion_energy() < 3.0 * work


def test_measured_force_keeps_its_friction_where_the_directional_decoupling_turns_singular():
    """Noise-free synthesised angles of a sliding contact decouple back to the simulated force,
    also where the friction direction makes the directional system singular (beam axis, x)."""
    from arsurf.assembly import LEVER, make_model
    from arsurf.model import (M_CONDITION, M_IN_CONTACT, M_LOAD, M_MEAS_FX, M_SIM_FX, SIGNALS_SYNTHESISED,
                              model_tick_kernel)
    from arsurf.spline.surface import BSplineSurface

    x = np.arange(64) * 4e-9
    z = 3e-9 * np.sin(2 * np.pi * x / 120e-9)
    surf = BSplineSurface.from_heights(np.tile(z, (64, 1)).T, (0.0, x[-1]), (0.0, x[-1]))
    m = make_model(surf, tip_radius=20e-9, effective_modulus=10e9, work_of_adhesion=0.1, cantilever=LEVER,
                   friction=0.2, deform=False)
    (proj, ctrl, rest, ku, kv, patch, md, dec, radius, fric, deform, state, coll, decout, ev, out) = m.kernel_args()
    worst, conds = 0.0, []
    for k in range(400):  # along x, the slip direction turning through the beam axis at k = 200
        cx = 60e-9 + 0.25e-9 * k
        cz = float(surf.evaluate(cx, 128e-9)[2]) + 20e-9 - 1.5e-9
        model_tick_kernel(proj, ctrl, rest, ku, kv, patch, md, dec, radius, fric, deform, cx,
                          128e-9 + 2e-12 * (k - 200) ** 2, cz, 0.0, 0.0, SIGNALS_SYNTHESISED, state, coll, decout,
                          ev, out)
        if out[M_IN_CONTACT] > 0.5 and k > 5:
            err = np.abs(out[M_MEAS_FX:M_MEAS_FX + 3] - out[M_SIM_FX:M_SIM_FX + 3]).max() / abs(out[M_LOAD])
            worst = max(worst, float(err))
            conds.append(out[M_CONDITION])
    assert max(conds) > 300  # the slide crosses the ill-conditioned band
    assert worst < 1e-6


def test_photodiode_noise_is_not_amplified_where_the_friction_direction_sweeps_through_the_beam_axis():
    """The demo's buzz at the start of its slide, reduced to the model: the friction direction
    turns through the beam axis (x), the directional system's noise gain grows as 1/|det|, and
    the angles carry the demo's photodiode noise. Weighing the directional F_x (noise error) and
    the fallback's (model error, at most mu_s P) by their inverse variances keeps the blend's
    error below sigma_B / 2 = mu_s P / 2 wherever the noise gain is large (before: the directional
    answer passed up to condition 100, ~40 nN rms on a 110 nN load there), and at the noise level
    where the system is well conditioned."""
    from arsurf.assembly import LEVER, make_model
    from arsurf.model import (M_CONDITION, M_IN_CONTACT, M_LOAD, M_MEAS_FX, M_SIM_FX, SIGNALS_SYNTHESISED,
                              model_tick_kernel)
    from arsurf.spline.surface import BSplineSurface

    sigma, mu = 2e-7, 0.2  # rad rms on each angle (the demo's), friction coefficient
    x = np.arange(64) * 4e-9
    z = 3e-9 * np.sin(2 * np.pi * x / 120e-9)
    surf = BSplineSurface.from_heights(np.tile(z, (64, 1)).T, (0.0, x[-1]), (0.0, x[-1]))
    m = make_model(surf, tip_radius=20e-9, effective_modulus=10e9, work_of_adhesion=0.1, cantilever=LEVER,
                   friction=mu, deform=False, signal_noise=sigma)
    (proj, ctrl, rest, ku, kv, patch, md, dec, radius, fric, deform, state, coll, decout, ev, out) = m.kernel_args()
    noise = np.random.default_rng(1).standard_normal((400, 2)) * sigma
    err, cond, load = [], [], []
    for k in range(400):  # along x, the slip direction turning through the beam axis at k = 200
        cx = 60e-9 + 0.25e-9 * k
        cz = float(surf.evaluate(cx, 128e-9)[2]) + 20e-9 - 1.5e-9
        model_tick_kernel(proj, ctrl, rest, ku, kv, patch, md, dec, radius, fric, deform, cx,
                          128e-9 + 2e-12 * (k - 200) ** 2, cz, noise[k, 0], noise[k, 1], SIGNALS_SYNTHESISED, state,
                          coll, decout, ev, out)
        if out[M_IN_CONTACT] > 0.5 and k > 5:
            err.append(out[M_MEAS_FX] - out[M_SIM_FX])
            cond.append(out[M_CONDITION])
            load.append(out[M_LOAD])
    err, cond, load = np.array(err), np.array(cond), np.array(load)
    sigma_tau = sigma / m.cantilever.kernel_parameters()[2]  # the torsion noise as a force (N)
    crossing = cond > 30.0
    assert crossing.sum() >= 5 and cond.max() > 300  # the slide crosses the ill-conditioned band
    assert np.sqrt(np.mean(err[crossing] ** 2)) < 0.5 * mu * load[crossing].min()
    well = cond < 10.0  # there the directional answer is kept, with its small noise gain
    assert np.sqrt(np.mean(err[well] ** 2)) < 2.0 * sigma_tau


def test_a_contact_point_jumping_to_the_next_asperity_keeps_its_friction():
    """The closest point jumps 1 nm while the tip moves 1 pm: the anchor is carried along, the
    friction stays what it was (before: the stretch to the old anchor reversed, and so did the
    friction, mu_k P in one tick)."""
    from arsurf.contact import friction as fr

    state = np.full(fr.STATE_SIZE, np.nan)
    state[fr.SLIPPING] = 0.0
    out = np.zeros(7)
    n, load, k_t = (0.0, 0.0, 1.0), 1e-7, 10.0
    for k in range(40):  # slide along +x: the friction settles at -mu_k P along x
        fr.stick_slip_kernel(1e-10 * k, 0.0, 0.0, *n, 1e-10 * k, 0.0, 20e-9, False, load, k_t, 0.2, 0.2, state, 0, out)
    before = out[:3].copy()
    assert before[0] == pytest.approx(-0.2 * load)
    fr.stick_slip_kernel(1e-10 * 39 - 1e-9, 0.0, 0.0, *n, 1e-10 * 39 + 1e-12, 0.0, 20e-9, False, load, k_t, 0.2, 0.2,
                         state, 0, out)  # the contact point jumps back 1 nm: another asperity
    np.testing.assert_allclose(out[:3], before, rtol=0, atol=1e-12 * load)


def test_a_jump_known_from_the_basin_change_keeps_the_friction_however_fast_the_tip_moves():
    """A 150 nm/s stroke at 1 kHz moves the tip 0.18 nm per tick; the contact point hops 1.6 nm
    across a valley: less than 10 times the tip's move, so the ratio test alone took it for a
    slide and the friction turned towards the old anchor (y reversed in one tick). Flagged as a
    basin change (``jumped``), the anchor is carried along and the friction stays."""
    from arsurf.contact import friction as fr

    state = np.full(fr.STATE_SIZE, np.nan)
    state[fr.SLIPPING] = 0.0
    out = np.zeros(7)
    n, load, k_t, step = (0.0, 0.0, 1.0), 1e-7, 10.0, 0.18e-9
    for k in range(40):  # slide along +x: the friction settles at -mu_k P along x
        fr.stick_slip_kernel(step * k, 0.0, 0.0, *n, step * k, 0.0, 20e-9, False, load, k_t, 0.2, 0.2, state, 0, out)
    before = out[:3].copy()
    saved = state.copy()
    args = (step * 40, -1.6e-9, 0.0, *n, step * 40, 0.0, 20e-9)  # the tip moves on, the point hops 1.6 nm in y
    fr.stick_slip_kernel(*args, False, load, k_t, 0.2, 0.2, state, 0, out)
    assert out[1] > 0.5 * 0.2 * load  # unflagged: the friction turned towards +y (the reversal)
    state[:] = saved
    fr.stick_slip_kernel(*args, True, load, k_t, 0.2, 0.2, state, 0, out)
    np.testing.assert_allclose(out[:3], before, rtol=0, atol=1e-9 * load)


@pytest.mark.parametrize("motion, source", [("stroke", "simulated"), ("slide-10", "measured")])
def test_a_contact_hopping_between_two_slopes_of_the_real_jpk_scan_does_not_buzz(motion, source):
    """sample_0.jpk at 1 kHz: the closest point hops between two slopes of a valley. In the
    stroke the hop (1.6 nm) was shorter than 10 tip moves, the friction anchor stayed behind and
    the friction reversed (2 reversals, ~6 mN at the hand); in the 10 nm/s slide the closest point
    jumped back into the basin of the second contact being followed, which was then dropped
    instead of swapped, and the normal stepped back for a tick (1 reversal of 0.16 mN)."""
    from tests.support.real_scans import real_scan_path

    from arsurf.feel_scenarios import prepared_surface, run_scenario
    from arsurf.haptics.feel import reversal_ticks

    surface = prepared_surface(real_scan_path("sample_0.jpk"))[1]
    run = run_scenario(surface, motion=motion, source=source, rate=1000.0)
    assert not reversal_ticks(run.force, 1e-3).any(), run.score.summary()
    assert not run.score.buzzes, run.score.summary()
    assert run.transparency == pytest.approx(1.0, abs=1e-3)


@pytest.mark.parametrize("rate", [1000.0, 10000.0])
def test_sliding_across_a_rough_real_scan_has_no_friction_steps(rate):
    """Veeco scan, 10 nm/s: where the contact passed to the next asperity the friction reversed
    (7 mN steps at the hand at 10 kHz, 2 reversals at 1 kHz)."""
    from tests.support.real_scans import real_scan_path

    from arsurf.feel_scenarios import prepared_surface, run_scenario

    surface = prepared_surface(real_scan_path("Veeco_20160622.003"))[1]
    run = run_scenario(surface, motion="slide-10", source="simulated", rate=rate)
    assert not run.score.buzzes, run.score.summary()
    after = int(rate)  # after the press
    assert np.linalg.norm(np.diff(run.force[after:], axis=0), axis=1).max() < 1.5e-3
