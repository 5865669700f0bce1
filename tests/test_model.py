"""The per-tick model: collision on the rest surface, MD with hysteresis, dent, both forces."""
import numpy as np
import pytest

from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.errors import ContactError
from arsurf.force.cantilever import Cantilever
from arsurf.model import ARModel
from arsurf.spline.surface import BSplineSurface

R = 20e-9
LEVER = Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27)


@pytest.fixture
def flat():
    return BSplineSurface.from_heights(np.zeros((60, 60)), (0.0, 57 * 4e-9), (0.0, 57 * 4e-9))


@pytest.fixture
def md():
    return MaugisDugdale(R, 50e9, 0.1)


def test_pressing_on_a_flat_gives_the_md_load_along_z_and_a_dent(flat, md):
    m = ARModel(flat, R, md, LEVER, friction=0.0)
    t = m.step((100e-9, 100e-9, R - 1e-9))
    assert t.in_contact and t.md_status == 0
    np.testing.assert_allclose(t.normal, [0, 0, 1], atol=1e-14)
    assert t.depth == pytest.approx(1e-9, rel=1e-12)
    assert t.load == pytest.approx(md.load(1e-9), rel=1e-9)
    assert t.contact_radius == pytest.approx(md.contact_radius(depth=1e-9), rel=1e-9)
    np.testing.assert_allclose(t.simulated_force, [0, 0, t.load], atol=1e-24)
    assert t.moved > 0 and flat.is_deformed
    assert np.isnan(t.measured_force).all()


def test_approach_retract_hysteresis_and_return_to_rest(flat):
    md = MaugisDugdale(R, 2e9, 0.1)  # a soft polymer: lambda = 1.42, jump-out well below jump-in
    assert md.jump_out_depth() < 2 * md.jump_in_depth() < 0
    m = ARModel(flat, R, md, LEVER)
    zs = np.r_[np.linspace(R + 3e-9, R - 1e-9, 201), np.linspace(R - 1e-9, R + 3e-9, 201)]
    loads = np.array([m.step((100e-9, 100e-9, z)).load for z in zs])
    approach, retract = loads[:201], loads[201:][::-1]
    # on retraction the adhesive neck holds: tensile loads where the approach saw none
    assert retract.min() < 0.0 and retract.min() <= md.pull_off_force() * 0.9
    assert np.any((approach == 0.0) & (retract < 0.0))
    assert loads[-1] == 0.0 and not flat.is_deformed


def test_measured_force_recovers_the_simulated_one_through_the_cantilever(flat, md):
    m = ARModel(flat, R, md, LEVER, friction=0.3)
    c = np.array([100e-9, 100e-9, R - 1.5e-9])
    v = np.array([0.3e-6, 1e-6, 0.0])  # sliding obliquely to the beam: well conditioned
    sim = m.step(c, v).simulated_force
    assert sim[1] < 0 and sim[0] < 0  # friction opposes the motion
    m.reset()
    t = m.step(c, v, signals=LEVER.angles(sim))
    np.testing.assert_allclose(t.measured_force, sim, rtol=1e-9)
    assert t.decoupling_flags == 0


def test_bad_input(flat, md):
    with pytest.raises(ContactError, match="tip_radius` must be positive"):
        ARModel(flat, 0.0, md, LEVER)
    with pytest.raises(ContactError, match="differs from tip_radius"):
        ARModel(flat, 10e-9, md, LEVER)
    with pytest.raises(ContactError, match="friction"):
        ARModel(flat, R, md, LEVER, friction=-1)
    m = ARModel(flat, R, md, LEVER)
    with pytest.raises(ContactError, match="center"):
        m.step((np.nan, 0, 0))
    with pytest.raises(ContactError, match="signals"):
        m.step((1e-7, 1e-7, 1e-8), signals=(np.nan, 0.0))


def test_out_of_contact_the_measured_force_is_the_classical_reading(flat, md):
    """No contact, no normal to decouple with: all bending is F_z, torsion is F_y (flagged)."""
    from arsurf.force.decoupling import DecouplingFlag

    m = ARModel(flat, R, md, LEVER)
    t = m.step((100e-9, 100e-9, R + 10e-9), (1e-6, 0.0, 0.0), signals=(2e-6, -1e-7))
    assert t.md_status == 2 and not t.in_contact
    np.testing.assert_allclose(t.measured_force, [0.0, -1e-7 / LEVER.torsion_compliance, 2e-6 / LEVER.bending_compliance],
                               rtol=1e-15)
    assert t.decoupling_flags == DecouplingFlag.FALLBACK_DEGENERATE


def test_friction_is_coulomb_when_sliding_and_fades_out_when_standing_still(flat, md):
    from arsurf.model import FRICTION_VELOCITY

    m = ARModel(flat, R, md, LEVER, friction=0.3)
    c = (100e-9, 100e-9, R - 1e-9)
    fast = m.step(c, (5 * FRICTION_VELOCITY, 0.0, 0.0))
    assert fast.simulated_force[0] == pytest.approx(-0.3 * fast.load, rel=1e-12)   # Coulomb: mu P
    slow = m.step(c, (0.1 * FRICTION_VELOCITY, 0.0, 0.0))
    assert slow.simulated_force[0] == pytest.approx(-0.03 * slow.load, rel=1e-12)  # viscous below v_eps
    still = m.step(c, (0.0, 0.0, -1e-6))
    assert still.simulated_force[0] == 0.0 and still.simulated_force[1] == 0.0


def test_no_friction_direction_is_guessed_from_jitter_below_the_friction_velocity(flat, md):
    """Standing (|v_h| < FRICTION_VELOCITY) the tip's jitter gives no friction direction: the
    decoupling must not take one from it. With 0.2 urad of signal noise, a jitter direction near the
    beam axis made the system ill-conditioned and turned the noise into hundreds of nN at pull-off
    in the demo. The fallback (force along the normal plus the torsion) can miss at most the small
    regularised friction it cannot see, plus the noise."""
    from arsurf.force.decoupling import DecouplingFlag
    from arsurf.model import FRICTION_VELOCITY

    rng = np.random.default_rng(5)
    m = ARModel(flat, R, md, LEVER, friction=0.3)
    c = (100e-9, 100e-9, R - 1e-9)
    for _ in range(500):
        angle = rng.uniform(0.0, 2 * np.pi)
        v = 0.5 * FRICTION_VELOCITY * np.array([np.cos(angle), np.sin(angle), 0.0])
        sim = m.step(c, v).simulated_force
        t = m.step(c, v, signals=np.array(LEVER.angles(sim)) + rng.normal(0.0, 2e-7, 2))
        assert t.decoupling_flags & DecouplingFlag.NO_MOTION
        unseen = np.hypot(sim[0], sim[1])                    # the friction, 0.15 of the load here
        assert np.abs(t.measured_force - sim).max() <= unseen + 3e-9
