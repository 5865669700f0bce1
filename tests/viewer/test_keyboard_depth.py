"""The keyboard's stand-in stylus stays where the contact model holds (issue #30, "Traps"): twelve
Page Down presses once drove a 20 nm tip 75.9 nm into polystyrene (14.8 uN, a = 2 R) unflagged.
The vertical step scales with the tip radius, Page Down stops at the depth where the contact
reaches the law's bound, and a state beyond it is named in the HUD."""
from __future__ import annotations

import numpy as np
import pytest

from arsurf.contact.mechanics import SMALL_CONTACT_LIMIT
from arsurf.spline.surface import BSplineSurface
from arsurf.status import BEYOND_MODEL, CLAMPED
from arsurf_viewer.interactive import ContactPhysics, StylusController
from arsurf_viewer.state import SceneState

R = 20e-9


def _flat(size=1.2e-6):
    return BSplineSurface.from_heights(np.zeros((40, 40)), (0.0, size), (0.0, size))


def test_twelve_page_downs_stay_within_the_contact_law():
    s = _flat()
    physics = ContactPhysics(s, R)  # Si on polystyrene, as `arsurf view`
    # where run_interactive starts the tip, with the depth limit of the law in use
    ctl = StylusController(s, (0.6e-6, 0.6e-6, 2.5 * R), R, max_depth=physics.max_depth)
    assert ctl.z_step == pytest.approx(R / 10)
    # adhesion widens the contact: the bound comes sooner than Hertz's 0.16 R
    assert 0.05 * R < physics.max_depth < SMALL_CONTACT_LIMIT ** 2 * R
    assert StylusController(s, (0, 0, R), R).max_depth == pytest.approx(SMALL_CONTACT_LIMIT ** 2 * R)
    deepest = 0.0
    for _ in range(40):  # held down well past where it used to go
        ctl.handle_key("Next")
        state = physics(ctl.tip_center, 1 / 30)
        ctl.depth = state.depth  # what run_interactive does each frame
        deepest = max(deepest, state.depth)
        assert not state.flags & BEYOND_MODEL, (state.depth, state.contact_radius)
    assert ctl.max_depth - 1e-15 <= deepest <= ctl.max_depth + 1e-12  # it reached the limit, not past it
    assert "depth limit" in ctl.handle_key("Next")
    assert ctl.handle_key("Prior").startswith("tip at")  # lifting is always allowed


def test_presses_between_frames_count_towards_the_limit():
    ctl = StylusController(_flat(), (0.0, 0.0, R), R)
    ctl.depth = 0.0  # touching
    z0 = ctl.tip_center[2]
    for _ in range(10):  # ten presses before the next frame reports a depth
        ctl.handle_key("Next")
    assert z0 - ctl.tip_center[2] == pytest.approx(ctl.max_depth)


@pytest.mark.viewer
def test_the_hud_names_a_state_beyond_the_model(gl):
    from arsurf_viewer import SurfaceView

    s = _flat(200e-9)
    view = SurfaceView(s, window_size=(400, 300), off_screen=True, anti_aliasing=None)
    try:
        st = SceneState(s, (100e-9, 100e-9, R - 30e-9), R, depth=30e-9, contact_radius=1.1 * R,
                        force=(0, 0, 1e-6), flags=BEYOND_MODEL | CLAMPED)
        view.update(st)
        text = view.hud_actor.GetInput()
        assert "BEYOND MODEL: contact radius 1.10 R > 0.4 R" in text and "flags: CLAMPED" in text, text
        view.update(SceneState(s, (100e-9, 100e-9, R), R))
        assert "BEYOND" not in view.hud_actor.GetInput()
    finally:
        view.close()
