"""The stick-slip friction proxy (arsurf.contact.friction): mu_k (P + |P_c|) on a steady slide, a
spring on the tip's own tangential move."""
import math

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


def test_the_spring_stretches_only_along_the_surface_however_the_normal_turns():
    """A stuck tip pressed 2 nm along the normal feels no friction; when the normal then turns by
    0.2 rad under the still tip, none either: the anchor follows the tip along the normal. (Kept
    behind, the 2 nm press became a 0.4 nm tangential stretch: 4 nN of friction from nothing.)"""
    from arsurf.contact import friction as fr

    state = np.full(fr.STATE_SIZE, np.nan)
    state[fr.SLIPPING] = 0.0
    out = np.zeros(fr.OUT_SIZE)
    k_t, limit = 10.0, 1e-7
    for k in range(21):  # pressed straight down, 0.1 nm a tick, on a flat
        assert fr.stick_slip_kernel(0.0, 0.0, -0.1e-9 * k, 0.0, 0.0, 1.0, limit, limit, k_t, state, 0, out) == 0
        np.testing.assert_allclose(out[fr.O_FORCE:fr.O_FORCE + 3], 0.0, rtol=0, atol=1e-24)
    t = 0.2
    fr.stick_slip_kernel(0.0, 0.0, -2e-9, math.sin(t), 0.0, math.cos(t), limit, limit, k_t, state, 0, out)
    assert np.abs(out[fr.O_FORCE:fr.O_FORCE + 3]).max() <= 1e-12 * k_t * 2e-9
    fr.stick_slip_kernel(0.1e-9, 0.0, -2e-9, math.sin(t), 0.0, math.cos(t), limit, limit, k_t, state, 0, out)
    tangent = np.array([math.cos(t), 0.0, -math.sin(t)])  # then a move along x stretches along the tangent
    np.testing.assert_allclose(out[fr.O_FORCE:fr.O_FORCE + 3], -k_t * 0.1e-9 * math.cos(t) * tangent,
                               rtol=1e-9, atol=1e-9 * k_t * 1e-10)


def test_in_a_hollow_about_as_wide_as_the_tip_the_stuck_friction_is_mindlin_s_spring_on_the_tip_s_move():
    """Mindlin's k_t acts on the tip's own tangential displacement (Johnson 1985, Sec. 7.2). At
    the bottom of a bowl of curvature radius rho = 1.3 R, the closest point runs
    rho / (rho - (R - delta)) = 3.2 times ahead of a tip delta = 0.5 nm deep; measured there, the
    stuck friction came out 2.9 k_t per metre the tip moved (387 N/m for 132)."""
    from arsurf.contact import friction as fr
    from arsurf.contact.maugis_dugdale import MaugisDugdale
    from arsurf.model import ARModel
    from arsurf.spline.surface import BSplineSurface
    from tests.support.valleys import LEVER

    r_tip, rho, pitch = 5e-9, 6.5e-9, 0.25e-9
    x = (np.arange(81) - 40) * pitch
    bowl = (x[:, None] ** 2 + x[None, :] ** 2) / (2.0 * rho)
    law = MaugisDugdale(r_tip, 50e9, 0.05)
    forces = {}
    for mu in (0.0, 0.3):
        s = BSplineSurface.from_heights(bowl, (x[0], x[-1]), (x[0], x[-1]))
        m = ARModel(s, r_tip, law, LEVER, friction=mu, deform=False)
        for k in range(20):  # straight down onto the bottom, 0.5 nm deep
            m.tick((0.0, 0.0, r_tip - 0.5e-9 + (20 - k) * 0.2e-9))
        t0 = m.step((0.0, 0.0, r_tip - 0.5e-9))
        t1 = m.step((2e-12, 0.0, r_tip - 0.5e-9))  # 2 pm sideways: stuck
        assert not t1.slipping
        forces[mu] = (t1.simulated_force - t0.simulated_force, t1.contact_radius)
    (plain, _), (rubbing, a) = forces[0.0], forces[0.3]
    k_t = -(rubbing[0] - plain[0]) / 2e-12  # N/m, the friction's share of the sideways stiffness
    assert k_t == pytest.approx(fr.MINDLIN_RATIO * 2.0 * law.effective_modulus * a, rel=0.02)
