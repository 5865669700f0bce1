r"""Passivity observer and controller on the device port (Hannaford & Ryu 2002).

A sampled haptic loop can create energy: the force is held over a tick while the hand moves, and
a stiff virtual contact returns more energy on the way out than it took on the way in (the
virtual-wall limit of Colgate & Schenkel 1997). The *passivity observer* sums, tick by tick, the
energy that has flowed from the hand into the virtual environment through the device port,

.. math:: E_n = -\sum_{k=1}^{n} f_{k-1}\cdot(x_k - x_{k-1}),

exact for a force :math:`f_{k-1}` held (zero-order hold) while the handle moves from
:math:`x_{k-1}` to :math:`x_k`: it uses the force the device actually applied (after saturation
and ramps) and the handle's measured positions, no model. Passivity is :math:`E_n \ge -E_0`,
:math:`E_0` the energy the environment stores at the start: an adhesive contact holds a potential
well below the zero of a tip far away, and gives that energy back passively at snap-in (without
one, :math:`E_0 = 0`). The loop gives the controller the well's depth bound as ``reserve``
(:meth:`arsurf.model.ARModel.adhesion_energy` times the coupling's energy gain), so it damps only
what the sampled loop creates beyond it: a controller that fights the adhesion's own energy damps
every pull-off and chatters at its limit.

The *passivity controller* adds the damping that keeps :math:`E \ge -E_0` after the coming tick
too: the force :math:`f_n` about to be held gives the hand :math:`f_n\cdot v_n T` more at the
measured velocity :math:`v_n` (Hannaford & Ryu's observer sums :math:`f(k)\,v(k)\,T` up to the
current sample, the current force's power included), so

.. math::

    \alpha_n = \frac{f_n\cdot v_n\,T - E_n - E_0}{T\,\lVert v_n\rVert^2} \text{ where positive},
    \qquad f_n \leftarrow f_n - \alpha_n v_n ,

and then :math:`E_{n+1} \approx E_n - (f_n - \alpha_n v_n)\cdot v_n T = -E_0`. Damping only the
deficit already observed (:math:`\alpha_n = -(E_n + E_0)/T\lVert v_n\rVert^2`, the held force's own
output left out) cancels the coming tick's output at best: a compressed contact released into the
hand overdrew the store by a tick's output every tick, and a release of a few ticks spent more
than the whole store before the controller acted. On the feel table (``bench/feel.py``, seed 0) a
1000 nm/s slide under a 10 nm tip over a surface of 2 nm correlation length gave the hand 213 times
the store (:math:`-213\,E_0`, 1 kHz) in four ticks, as the tip came off an asperity it had been
pressed 19.5 nm onto; counting the coming tick it keeps :math:`-0.41\,E_0`, and the energy below
:math:`-E_0` summed over the table's 1 508 runs went from :math:`-292\,E_0` to :math:`-2.1\,E_0`
(docs/feel-log.rst).

The damping is limited to half the device's largest damping (:data:`DAMPING_FRACTION`: the controller's damper
acts on the last measured velocity, a tick late, and at the device's full limit it chatters
itself - measured on a stiff virtual wall, where half the limit keeps the wall passive and at
rest); the observer then sees that dissipation in the next tick's energy. A hand at rest (:math:`v = 0`) is never damped, so the steady force is untouched:
the controller costs transparency only while energy is being created, i.e. at high frequency.
Each tick reports the observed energy and the damping injected; a tick where the controller acted
carries the flag :data:`arsurf.status.PASSIVITY`.

State (:data:`PASSIVITY_STATE`): E (J), the previous handle position (m; NaN: none), the force
applied over the last tick (N), the damping injected this tick (N s/m).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from arsurf import status
from arsurf._layout import Layout
from arsurf.errors import HapticsError

#: the observer's state (module docstring): E (J), the previous handle position (m; NaN: none), the
#: force applied over the last tick (N), the damping injected this tick (N s/m)
PASSIVITY_STATE = Layout("passivity state", [("energy", 1), ("position", 3), ("force", 3), ("damping", 1)])
#: its parameters: the loop period (s), the damping limit (N s/m), 1 when the controller may damp,
#: the environment's energy reserve E_0 (J)
PASSIVITY_PARAMS = Layout("passivity parameters", [("dt", 1), ("max_damping", 1), ("on", 1), ("reserve", 1)])
# the offsets as the kernels use them
S_ENERGY, S_X = PASSIVITY_STATE.offset("energy"), PASSIVITY_STATE.offset("position")
S_F, S_ALPHA = PASSIVITY_STATE.offset("force"), PASSIVITY_STATE.offset("damping")
STATE_SIZE = PASSIVITY_STATE.size
P_DT, P_MAX_DAMPING = PASSIVITY_PARAMS.offset("dt"), PASSIVITY_PARAMS.offset("max_damping")
P_ON, P_RESERVE = PASSIVITY_PARAMS.offset("on"), PASSIVITY_PARAMS.offset("reserve")
PARAMS_SIZE = PASSIVITY_PARAMS.size
#: the controller's damping stays below this fraction of the device's ``max_damping``
DAMPING_FRACTION = 0.5


@njit(cache=True)
def passivity_observe_control(params, state, x, v, force) -> int:
    """Observe the energy of the last tick and damp ``force`` (3,) N in place where the energy
    after the coming tick would go below -E0 (module docstring).

    ``x``, ``v`` (3,) handle position (m) and velocity (m/s). Returns :data:`~arsurf.status.PASSIVITY`
    when damping was added, else 0. Non-finite positions skip the observation (the energy stays)."""
    state[S_ALPHA] = 0.0
    ok = True
    for j in range(3):
        if not (math.isfinite(x[j]) and math.isfinite(v[j])):
            ok = False
    if not ok:
        return 0
    if math.isfinite(state[S_X]):
        de = 0.0
        for j in range(3):
            de -= state[S_F + j] * (x[j] - state[S_X + j])
        state[S_ENERGY] += de
    for j in range(3):
        state[S_X + j] = x[j]
    v2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    coming = (force[0] * v[0] + force[1] * v[1] + force[2] * v[2]) * params[P_DT]  # what f gives over the tick
    deficit = -params[P_RESERVE] - state[S_ENERGY] + coming
    if params[P_ON] == 0.0 or not deficit > 0.0 or not v2 > 0.0:
        return 0
    alpha = min(deficit / (params[P_DT] * v2), params[P_MAX_DAMPING])
    if not math.isfinite(alpha * v2):  # a vanishing speed with no damping limit: nothing sensible to add
        return 0
    for j in range(3):
        force[j] -= alpha * v[j]
    state[S_ALPHA] = alpha
    return status.PASSIVITY


@njit(cache=True)
def passivity_applied(state, applied) -> None:
    """Remember the force (3,) N the device was given this tick (held until the next)."""
    for j in range(3):
        state[S_F + j] = applied[j] if math.isfinite(applied[j]) else 0.0


class PassivityController:
    """Parameters and state of the observer/controller (module docstring).

    Parameters
    ----------
    dt : float, s
        Loop period.
    max_damping : float, N s/m
        The device's largest damping; the controller adds at most :data:`DAMPING_FRACTION` of it
        (``inf``: no limit, only for simulations: near standstill the damping needed grows as 1/|v|).
    enabled : bool
        False: observe only (the energy is still logged, nothing is damped).
    reserve : float, J
        Energy the environment may give back passively (:math:`E_0`, module docstring; default 0).

    Examples
    --------
    >>> pc = PassivityController(1e-3, max_damping=5.0)
    >>> f = np.array([1.0, 0.0, 0.0])
    >>> _ = pc.step([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], f); pc.applied(f)
    >>> flag = pc.step([1e-3, 0.0, 0.0], [1.0, 0.0, 0.0], f)   # the force pushed the hand along: 1 mJ out
    >>> round(pc.energy, 6), round(pc.damping, 3), f.tolist()       # and 1 mJ more if held: damped to -1 N
    (-0.001, 2.0, [-1.0, 0.0, 0.0])
    """

    def __init__(self, dt: float, max_damping: float = math.inf, enabled: bool = True, reserve: float = 0.0):
        dt = float(dt)
        max_damping = float(max_damping)
        reserve = float(reserve)
        if not (math.isfinite(reserve) and reserve >= 0.0):
            raise HapticsError(f"reserve must be a finite energy >= 0 J (got {reserve!r})")
        if not (math.isfinite(dt) and dt > 0.0):
            raise HapticsError(f"dt must be positive (got {dt!r} s); it is the loop period")
        if not max_damping > 0.0:
            raise HapticsError(f"max_damping must be > 0 N s/m or inf (got {max_damping!r})")
        self.params = PASSIVITY_PARAMS.pack({"dt": dt, "max_damping": DAMPING_FRACTION * max_damping,
                                              "on": 1.0 if enabled else 0.0, "reserve": reserve})
        self.state = PASSIVITY_STATE.zeros()
        self.reset()

    def reset(self) -> None:
        """Zero the energy; forget the handle position and the held force."""
        self.state[:] = 0.0
        self.state[S_X:S_X + 3] = np.nan

    @property
    def energy(self) -> float:
        """Observed energy E (J): what the hand has put into the virtual environment, net."""
        return float(self.state[S_ENERGY])

    @property
    def reserve(self) -> float:
        """Energy the environment may give back passively, :math:`E_0` (J)."""
        return float(self.params[P_RESERVE])

    @property
    def damping(self) -> float:
        """Damping the controller injected at the last tick (N s/m)."""
        return float(self.state[S_ALPHA])

    def step(self, position, velocity, force) -> int:
        """Observe and control; ``force`` (3,) float array is damped in place. Returns the flag."""
        return int(passivity_observe_control(self.params, self.state, np.asarray(position, np.float64),
                                             np.asarray(velocity, np.float64), force))

    def applied(self, force) -> None:
        """Record the force the device was given this tick."""
        passivity_applied(self.state, np.asarray(force, np.float64))
