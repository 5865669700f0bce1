r"""A tube push under [MWCNT]'s conditions, and the normal force it gives against its Fig. 10a.

[MWCNT] Sec. 4.2 pushes a multi-walled nanotube lying on polycarbonate at one end, across its
axis (the first push of the "Z" strategy), with a k = 38.6 N/m lever, and records the forces of
Eq. 6 (Fig. 10): the lateral force saw-toothed at 0-30 nN, the normal force "well controlled at
about 20-40 nN with the assistance of force feedback". The normal force is the total vertical
force on the tip, the lever's bending (Eq. 6, :math:`F_z = k k_v S_v - F_y (h_t + b/2)/l_c`): the
substrate's reaction plus the tube's. The paper states no set point (its operator held the force
by hand, with the force feedback), no tip radius and no tube diameter.

:func:`run_tube_push` closes the whole loop as the demo does (:mod:`arsurf.demo.nanotubes`) but
without the engage, the recording and the replay: the preset's model (``mwcnt-push``: a 20 nm
silicon tip on polycarbonate, the paper's lever) on the bundled nanotubes scan, its tube scene,
the direct coupling with its virtual coupling and passivity controller, and a scripted hand
that presses the substrate to a held load (:func:`press_for_load`,
default :data:`HELD_LOAD`, the middle of Fig. 10a's range) and pushes a
tube end 50 nm across its axis. The normal force is then the model's own: the load on the
substrate (the held load, moved by the topography under the sliding tip at the grip's stiffness)
plus the vertical part of the tube's reaction. The tip is wider than the tube's radius, so its
centre lies above the tube's axis and the contact normal (axis to tip centre) tilts upward: the
frictionless contact force :math:`F_h` of the push (the substrate friction of the sliding tube,
:mod:`arsurf.manipulation.scene`) comes with an upward :math:`F_z = F_h\,\Delta z/d_h`, which
the hand's compliance shares with the substrate (docs/design.rst, "The normal force of a tube
push"). Forces in N, lengths in m, time in s.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from arsurf.assembly import BUNDLED_SCAN, build_loop, build_model, preset, preset_metadata
from arsurf.demo.nanotubes import hand_trajectory, plan_end_push
from arsurf.haptics.loop import LOOP_OUT
from arsurf.haptics.virtual_device import DEFAULT_HAND_STIFFNESS, HandModel, VirtualDevice
from arsurf.model import MODEL_OUT

__all__ = ["HELD_LOAD", "TubePush", "press_for_load", "run_tube_push"]

#: the load the scripted operator presses the substrate to before pushing (N): the middle of the
#: 20-40 nN at which [MWCNT] Fig. 10a's operator kept the normal force during its tube push (the
#: paper gives no set point: its operator controlled the force by hand, with the force feedback);
#: the tube's reaction on its curved flank adds its vertical part during the push (docs/design.rst,
#: "The normal force of a tube push")
HELD_LOAD = 30e-9


def press_for_load(loop, load: float, hand_stiffness: float = DEFAULT_HAND_STIFFNESS) -> float:
    r"""How far past first touch (probe metres) the hand's set point must go for the tip to rest on
    a flat substrate at ``load`` (N), through ``loop`` (direct coupling) held by a hand of grip
    stiffness ``hand_stiffness`` (N/m, :class:`~arsurf.haptics.virtual_device.HandModel`).

    The grip :math:`K_h` acts on the tip through the direct coupling (force gain :math:`K_f`,
    scale :math:`s`) as a spring :math:`k_h = K_h/(K_f s)`, in series with the virtual coupling
    :math:`k_{vc}` (the model's, at the probe). At rest the stretch of that chain carries the
    load, :math:`P = k\,(i - \delta(P))` with :math:`1/k = 1/k_h + 1/k_{vc}` and :math:`\delta(P)`
    the depth of the model's Maugis-Dugdale law at :math:`P` (load control), so

    .. math:: i = \delta(P) + P/k.

    The grip is the operator's lever: like the cantilever of an AFM, it sets the load by its
    deflection (22 N/m at the probe with the demo's hand, device and gains; [MWCNT]'s lever is 38.6 N/m).
    """
    gain = float(np.broadcast_to(np.asarray(loop.coupling.force.gain, dtype=np.float64), (3,))[2])
    scale = float(np.broadcast_to(np.asarray(loop.coupling.position.scale, dtype=np.float64), (3,))[2])
    k_hand = float(hand_stiffness) / (gain * scale)
    k = 1.0 / (1.0 / k_hand + 1.0 / loop.model.coupling_stiffness)
    return float(loop.model.contact.contact_state(load=load).depth) + load / k



#: the hand hovers this far above the substrate (probe m) before it approaches (the demo's)
HOVER = 8e-9


@dataclass(frozen=True)
class TubePush:
    """The record of :func:`run_tube_push`, one row per tick.

    Attributes
    ----------
    time : (n,) s
    contact_force : (n, 3) N
        The substrate's force on the tip (the model's simulated force: Maugis-Dugdale load along
        the contact normal plus friction).
    tube_force : (n, 3) N
        The tubes' reaction on the tip (:attr:`arsurf.manipulation.scene.TubeScene.force`).
    tip : (n, 3) m
        The tip centre.
    device_force : (n, 3) N
        The force commanded to the hand (the feel: :func:`arsurf.haptics.feel.score_force`).
    load : (n,) N
        The Maugis-Dugdale load on the substrate (NaN out of contact).
    held_load : float, N
        The load the hand pressed to.
    tube, end : int, str
        The pushed tube and end.
    tube_radius, tip_radius, axis_height : float, m
    """

    time: np.ndarray
    contact_force: np.ndarray
    tube_force: np.ndarray
    tip: np.ndarray
    device_force: np.ndarray
    load: np.ndarray
    held_load: float
    tube: int
    end: str
    tube_radius: float
    tip_radius: float
    axis_height: float

    @property
    def normal_force(self) -> np.ndarray:
        """(n,) N: the total vertical force on the tip, substrate plus tube (what [MWCNT] Eq. 6 measures)."""
        return self.contact_force[:, 2] + self.tube_force[:, 2]

    @property
    def pushing(self) -> np.ndarray:
        """(n,) bool: ticks where the tube pushes back on the tip."""
        return np.hypot(self.tube_force[:, 0], self.tube_force[:, 1]) > 0.0


def run_tube_push(preset_name: str = "mwcnt-push", *, held_load: float = HELD_LOAD, scan=BUNDLED_SCAN,
                  seconds: float = 5.0) -> TubePush:
    """Press to ``held_load`` (N) and push a tube end 50 nm across its axis through the whole loop.

    ``preset_name``: a :data:`arsurf.assembly.PRESETS` name (its tip, contact law, lever and haptic
    settings); ``scan``: a synthetic nanotubes scan (its tubes become the scene); ``seconds`` of
    simulated time at the preset's rate (the push runs from 2.3 to 4.3 s, the retract after).
    """
    from arsurf.manipulation.scene import TubeScene
    from arsurf.scan.prepare import prepare_scan

    p = preset(preset_name)
    rate = float(p.haptics["rate"])
    prepared = prepare_scan(scan, None, p.level, p.sigma, True)
    meta = preset_metadata(scan, p, tubes=TubeScene.from_scan(prepared).to_metadata())
    setup = build_model(meta)
    model, scene, surface = setup.model, setup.scene, setup.surface
    plan = plan_end_push(scene, setup.scan, p.tip_radius)
    (x0, y0), direction, slide = plan["start"], plan["direction"], plan["slide"]
    ring = np.linspace(-1.5, 1.5, 31) * p.tip_radius
    z_top = float(surface.evaluate(x0 + ring, np.full(31, y0))[:, 2].max())  # the highest point the tip can touch
    origin = (x0, y0, z_top + p.tip_radius + HOVER)
    loop = build_loop(model, setup.config.haptics, VirtualDevice(dt=1.0 / rate).info, origin, scene=scene, seed=7,
                      ramp_time=0.2)
    hand = HandModel(hand_trajectory(HOVER, press_for_load(loop, held_load), slide, direction))
    dev = VirtualDevice(dt=1.0 / rate, hand=hand).open()
    n = int(seconds * rate)
    contact, tube, tip, felt = (np.empty((n, 3)) for _ in range(4))
    load = np.empty(n)
    sim, m_load = MODEL_OUT.slice("simulated_force"), MODEL_OUT.offset("load")
    l_tip = LOOP_OUT.slice("tip")
    try:
        for k in range(n):
            st = dev.read_state()
            felt[k] = loop.step(st, st.timestamp)
            dev.command_force(felt[k])
            contact[k] = model.out[sim]
            tube[k] = scene.force
            tip[k] = loop.out[l_tip]
            load[k] = model.out[m_load]
    finally:
        dev.close()
    t = scene.initial[plan["tube"]]
    return TubePush(time=np.arange(n) / rate, contact_force=contact, tube_force=tube, tip=tip, device_force=felt, load=load,
                    held_load=float(held_load), tube=int(plan["tube"]), end=plan["end"], tube_radius=t.radius,
                    tip_radius=p.tip_radius, axis_height=t.axis_height)
