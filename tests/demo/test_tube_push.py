"""A tube push under [MWCNT]'s conditions (arsurf.demo.tube_push): its normal force against the
paper's Fig. 10a (20-40 nN), from the held load and the tube's reaction on its curved flank."""
from __future__ import annotations

import numpy as np
import pytest

from arsurf.demo.tube_push import HELD_LOAD, run_tube_push
from arsurf.manipulation.scene import CONTACT_ALLOWANCE

#: [MWCNT] Fig. 10: the normal force "well controlled at about 20-40 nN", the lateral force 0-30 nN
FIG10_NORMAL = (20e-9, 40e-9)
FIG10_LATERAL = 30e-9


@pytest.fixture(scope="module")
def push():
    return run_tube_push("mwcnt-push", seconds=4.3)  # press (to 2.3 s), slide and push (2.3-4.3 s)


def test_the_normal_force_of_a_tube_push_is_in_fig10a_range(push):
    """While the tube pushes back, the total vertical force on the tip (substrate plus tube, what
    [MWCNT] Eq. 6 measures) stays in Fig. 10a's 20-40 nN, and the end push's lateral force in
    Fig. 10b's 0-30 nN."""
    pushing = push.pushing
    assert pushing.sum() > 500                                   # the tube resisted for > 0.5 s
    normal = push.normal_force[pushing]
    assert FIG10_NORMAL[0] <= normal.min() and normal.max() <= FIG10_NORMAL[1]
    lateral = np.hypot(push.tube_force[pushing, 0], push.tube_force[pushing, 1])
    assert lateral.max() <= FIG10_LATERAL


def test_press_for_load_holds_the_load_on_a_flat_substrate():
    """press_for_load: the hand's set point past first touch, through the grip and the virtual
    coupling in series and the Maugis-Dugdale depth at the load, gives that load at rest (and
    while sliding: friction is tangential on a flat substrate)."""
    from arsurf.assembly import PRESETS, build_loop, make_model
    from arsurf.demo.nanotubes import hand_trajectory
    from arsurf.demo.tube_push import press_for_load
    from arsurf.haptics.virtual_device import HandModel, VirtualDevice
    from arsurf.model import MODEL_OUT
    from arsurf.spline.surface import BSplineSurface

    p = PRESETS["mwcnt-push"]
    flat = BSplineSurface.from_heights(np.zeros((16, 16)), (0.0, 400e-9), (0.0, 400e-9))
    model = make_model(flat, tip_radius=p.tip_radius, effective_modulus=p.effective_modulus,
                       work_of_adhesion=p.work_of_adhesion, friction=p.friction)
    loop = build_loop(model, p.haptics, VirtualDevice(dt=1e-3).info, (100e-9, 200e-9, p.tip_radius + 8e-9),
                      ramp_time=0.2)
    dev = VirtualDevice(dt=1e-3, hand=HandModel(hand_trajectory(8e-9, press_for_load(loop, HELD_LOAD), 100e-9,
                                                                (1.0, 0.0)))).open()
    fz = np.empty(4000)
    for k in range(fz.size):
        st = dev.read_state()
        dev.command_force(loop.step(st, st.timestamp))
        fz[k] = model.out[MODEL_OUT.slice("simulated_force")][2]
    assert fz[2600:].min() == pytest.approx(HELD_LOAD, rel=2e-3)     # pressed at 2.3 s, sliding from 2.3 s
    assert fz[2600:].max() == pytest.approx(HELD_LOAD, rel=2e-3)


def test_the_tube_adds_the_vertical_part_of_its_reaction_on_the_curved_flank(push):
    """The tip (R = 20 nm) is wider than the tube's radius: its centre lies above the axis and the
    contact normal (axis to tip centre) tilts upward, so the tube's reaction lifts the tip with
    F_z = F_h dz / d_h, d_h = sqrt(D^2 - dz^2), D the centre-axis distance ((R + r) less at most
    the contact allowance). The normal force rises above the load the tip held before the push
    (by the share of F_z the hand's compliance takes: the substrate unloads by the rest)."""
    pushing = push.pushing
    fz = push.tube_force[pushing, 2]
    fh = np.hypot(push.tube_force[pushing, 0], push.tube_force[pushing, 1])
    dz = push.tip[pushing, 2] - push.axis_height
    assert push.tip_radius > push.tube_radius and (dz > 0).all() and (fz > 0).all()
    reach = push.tip_radius + push.tube_radius
    lo = dz / np.sqrt(reach**2 - dz**2)                                     # tip just touching
    hi = dz / np.sqrt(((1 - CONTACT_ALLOWANCE) * reach) ** 2 - dz**2)       # tip in by the allowance
    assert (fz / fh >= lo * (1 - 1e-9)).all() and (fz / fh <= hi * (1 + 1e-9)).all()
    first = np.flatnonzero(pushing)[0]
    before = np.median(push.normal_force[first - 100:first])     # pressed, sliding towards the tube
    strong = fh > 0.5 * fh.max()
    assert np.median(push.normal_force[pushing][strong]) > before + 0.2 * np.median(fz[strong])

