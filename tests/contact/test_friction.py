"""The stick-slip friction proxy (arsurf.contact.friction): mu_k (P + |P_c|) on a steady slide, the
anchor carried across a jump of the contact point."""
import numpy as np
import pytest


def test_a_steady_slide_carries_mu_k_times_the_normal_force():
    """The default (adhesive) law: F_t = mu_k (P + |P_c|) through the whole loop."""
    from arsurf.assembly import preset
    from arsurf.contact.maugis_dugdale import MaugisDugdale
    from arsurf.feel_scenarios import run_scenario
    from arsurf.spline.surface import BSplineSurface

    flat = BSplineSurface.from_heights(np.zeros((128, 128)), (0.0, 127 * 4e-9), (0.0, 127 * 4e-9))
    run = run_scenario(flat, motion="slide-100", source="simulated", friction=0.2)
    f = run.probe_force[-1000:].mean(axis=0)
    p = preset("demo")
    pull_off = abs(MaugisDugdale(p.tip_radius, p.effective_modulus, p.work_of_adhesion).pull_off_force())
    assert not run.score.buzzes
    assert -f[0] / (f[2] + pull_off) == pytest.approx(0.2, rel=0.02)


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
        fr.stick_slip_kernel(1e-10 * k, 0.0, 0.0, *n, 1e-10 * k, 0.0, 20e-9, False, 0.2 * load, 0.2 * load, k_t, state, 0, out)
    before = out[:3].copy()
    assert before[0] == pytest.approx(-0.2 * load)
    fr.stick_slip_kernel(1e-10 * 39 - 1e-9, 0.0, 0.0, *n, 1e-10 * 39 + 1e-12, 0.0, 20e-9, False, 0.2 * load, 0.2 * load, k_t,
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
        fr.stick_slip_kernel(step * k, 0.0, 0.0, *n, step * k, 0.0, 20e-9, False, 0.2 * load, 0.2 * load, k_t, state, 0, out)
    before = out[:3].copy()
    saved = state.copy()
    args = (step * 40, -1.6e-9, 0.0, *n, step * 40, 0.0, 20e-9)  # the tip moves on, the point hops 1.6 nm in y
    fr.stick_slip_kernel(*args, False, 0.2 * load, 0.2 * load, k_t, state, 0, out)
    assert out[1] > 0.5 * 0.2 * load  # unflagged: the friction turned towards +y (the reversal)
    state[:] = saved
    fr.stick_slip_kernel(*args, True, 0.2 * load, 0.2 * load, k_t, state, 0, out)
    np.testing.assert_allclose(out[:3], before, rtol=0, atol=1e-9 * load)
