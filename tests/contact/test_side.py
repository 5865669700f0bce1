"""A tip pressed into a thin wall stays on the side it came from (arsurf.contact.side).

The wall is the feel table's ridge that popped through (issue 27, seed-12 sample): 19.1 nm high,
a Gaussian profile 3.8 nm wide (sigma 1.9 nm), under a 3.07 nm tip; the target is pushed
sideways through it 4 nm below its top, as a hand pressing harder than the contact can hold.
"""
import math

import numpy as np
import pytest

from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.model import ARModel
from arsurf.spline.surface import BSplineSurface
from tests.support.valleys import LEVER

R = 3.07e-9
HEIGHT, SIGMA = 19.1e-9, 1.91e-9
PIXEL, N = 0.393e-9, 96
X0 = (N - 1) * PIXEL / 2  # the ridge's middle plane, x = X0
Z = HEIGHT - 4e-9  # the target's height


@pytest.fixture(scope="module")
def ridge():
    x = np.arange(N) * PIXEL
    z = HEIGHT * np.exp(-0.5 * ((x - X0) / SIGMA) ** 2)
    return BSplineSurface.from_heights(np.tile(z, (N, 1)).T, (0.0, x[-1]), (0.0, x[-1]))


def _model(surface, coupling=math.inf):
    return ARModel(surface, R, MaugisDugdale(R, 5e9, 0.05), LEVER, friction=0.0, deform=False,
                   coupling_stiffness=coupling)


def _push(model, xs):
    """The x force (N) with the target at each x of ``xs`` (m), y in the middle, height Z."""
    y = X0
    return np.array([model.step((x, y, Z)).simulated_force[0] for x in xs])


@pytest.mark.parametrize("coupling", [math.inf, 5.0])
def test_a_target_pushed_through_a_thin_wall_keeps_being_pushed_back_the_way_it_came(ridge, coupling):
    m = _model(ridge, coupling)
    east = X0 + R + 4 * SIGMA  # clear of the ridge on its east side
    xs = np.linspace(east, X0 - 1.5e-9, 801)  # through the middle plane, 1.5 nm on
    fx = _push(m, xs)
    inside = xs < X0 + 1.0e-9
    assert fx[0] == 0.0 and fx[-1] > 0.0
    # the wall pushes the hand back east (+x) all the way, never west: no pop-through
    assert (fx[inside] > 0.0).all()
    steps = np.abs(np.diff(fx))
    assert steps.max() < 0.05 * np.abs(fx).max()  # no one-tick flip (it was 2x the force)
    # and it only grows as the target goes deeper: the wall stays a wall
    assert fx[-1] >= 0.999 * fx[inside].max()


def test_backing_out_retraces_the_push_and_forgets_the_side(ridge):
    m = _model(ridge)
    east = X0 + R + 4 * SIGMA
    xs = np.linspace(east, X0 - 1.0e-9, 401)
    fx_in = _push(m, xs)
    fx_out = _push(m, xs[::-1])[::-1]
    np.testing.assert_allclose(fx_out, fx_in, rtol=1e-9, atol=1e-18)  # no hysteresis, frictionless
    from arsurf.model import S_SIDE

    assert np.isnan(m.state[S_SIDE:S_SIDE + 3]).all()  # out of the wall: no side remembered


def test_a_target_coming_from_the_other_side_is_pushed_back_west(ridge):
    m = _model(ridge)
    west = X0 - R - 4 * SIGMA
    xs = np.linspace(west, X0 + 1.5e-9, 801)
    fx = _push(m, xs)
    inside = xs > X0 - 1.0e-9
    assert (fx[inside] < 0.0).all()


def test_a_target_pushed_through_a_flat_topped_wall_is_not_handed_from_face_to_face():
    """A flat-topped ridge (10 nm high, flanks exp(-(x/4 nm)^8)) pushed through 2 nm below its top:
    C crosses the bisector of the east flank and the top, where the global closest point jumps to the
    top (a face whose normal does not oppose the flank's), then the one between the top and the west
    flank. Handed on face by face, the memory let the target through: the hand pushed west by as much
    as it had been pushed east (-126 nN after +126 nN). Followed from the face it came in by, the target
    keeps the east flank until that face ends at the corner, then the top: pushed up, never west."""
    height, width = 10e-9, 4e-9
    x = np.arange(N) * PIXEL
    z = height * np.exp(-(np.abs((x - X0) / width) ** 8))
    wall = BSplineSurface.from_heights(np.tile(z, (N, 1)).T, (0.0, x[-1]), (0.0, x[-1]))
    m = _model(wall)
    xs = np.linspace(X0 + R + 2 * width, X0 - 1.5e-9, 1201)
    f = np.array([m.step((xx, X0, z.max() - 2e-9)).simulated_force for xx in xs])
    pressed = np.argmax(f[:, 0] > 0.1 * f[:, 0].max())
    assert f[pressed:, 0].min() > -0.05 * f[:, 0].max()  # never pushed west (it was -1.0 of the push)
    assert f[-1, 2] > 0.9 * np.linalg.norm(f[-1])  # on the top: pushed up
