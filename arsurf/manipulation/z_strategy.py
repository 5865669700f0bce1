r"""The "Z" strategy of [MWCNT]: move a nanotube to a goal pose by pushing its ends alternately.

A push near an end, perpendicular to the axis, turns the tube about the pivot of
:func:`~arsurf.manipulation.nanotube.rotation_centre` (about 0.29 L from the other end), which
needs the least force ([MWCNT], Sec. 3). With the contact at arc-length :math:`l_B = L - m`
(margin :math:`m`) or :math:`l_A = m`, pivot :math:`s_B = s(l_B)`, lever :math:`a = l_B - s_B`
and arm :math:`c = L/2 - s_B`, a push of :math:`d` (signed, along the tube normal :math:`\nu`)
turns and moves the tube, to first order, by

.. math::

    \Delta\theta = \sigma \frac{d}{a}, \qquad \Delta\nu = \frac{c}{a} d,
    \qquad \sigma = +1 \text{ (end B)}, \ -1 \text{ (end A)} .

Two kinds of alternating sequences follow ("macros"), both symmetric so that the
second-order drift along the axis cancels:

* **translate** (the "Z"): pushes ``h, 2h, ..., 2h, h`` all in the direction of travel on
  alternating ends; the angle swings between :math:`\pm h/a` about its start and returns to it,
  the centre moves :math:`2 n h c / a` along :math:`\nu`;
* **turn**: rotations ``phi/2, phi, ..., phi, phi/2`` on alternating ends (pushes in opposite
  directions on the two ends); the centre swings by :math:`\pm c\varphi/2` and returns.

Motion along the axis is obtained by turning the tube across the remaining offset first. The
planner is closed-loop on the model: every push is simulated with
:func:`~arsurf.manipulation.nanotube.push` exactly as the live loop or a replay would execute it
(tip approach from ``clearance`` away, push, lift), and the next macro is chosen from the
simulated pose, so the returned sequence reproduces its predicted poses when replayed. Between
pushes the tip is lifted above the tube and moved to the next start.

Examples
--------
>>> from arsurf.manipulation.nanotube import Nanotube
>>> tube = Nanotube(1e-6, 20e-9, x=0.0, y=0.0, angle=0.0)
>>> goal = Nanotube(1e-6, 20e-9, x=0.1e-6, y=0.3e-6, angle=0.4)
>>> plan = plan_z_pushes(tube, goal, tip_radius=10e-9, position_tolerance=10e-9,
...                      angle_tolerance=0.01)
>>> plan.converged, plan.position_error <= 10e-9
(True, True)
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from arsurf.errors import ManipulationError
from arsurf.manipulation.nanotube import Nanotube, push, rotation_centre


def _wrap_half(angle: float) -> float:
    """Angle modulo pi into (-pi/2, pi/2]: a tube is symmetric end for end."""
    a = math.fmod(angle, math.pi)
    if a > 0.5 * math.pi:
        a -= math.pi
    elif a <= -0.5 * math.pi:
        a += math.pi
    return a


@dataclass(frozen=True)
class PlannedPush:
    """One push of a plan: where the tip starts, how it moves, what the model predicts.

    Attributes
    ----------
    start : (3,) float, metres
        Tip-sphere centre where the push begins, ``clearance`` away from the tube.
    displacement : (3,) float, metres
        Straight move of the tip (horizontal, at the tube's axis height).
    end : str
        ``"A"`` or ``"B"``: the end pushed.
    before, after : Nanotube
        Tube before the push and as :func:`push` predicts after it.
    """

    start: np.ndarray
    displacement: np.ndarray
    end: str
    before: Nanotube
    after: Nanotube


@dataclass(frozen=True)
class PushPlan:
    """A sequence of pushes from :func:`plan_z_pushes` and how close it gets.

    Attributes
    ----------
    pushes : list of PlannedPush
    tube : Nanotube
        Predicted final tube.
    converged : bool
        Whether the final pose is within both tolerances.
    position_error : float, metres
        Distance from the final centre to the goal centre.
    angle_error : float, radians
        Final axis-angle error (goal minus final), modulo pi unless ``match_ends``.
    """

    pushes: list = field(default_factory=list)
    tube: Nanotube | None = None
    converged: bool = False
    position_error: float = math.inf
    angle_error: float = math.inf


def plan_z_pushes(tube: Nanotube, goal, tip_radius: float, *, position_tolerance: float,
                  angle_tolerance: float, end_margin: float = 0.1, max_rotation: float = 0.15,
                  clearance: float | None = None, max_pushes: int = 1000,
                  match_ends: bool = False) -> PushPlan:
    r"""Plan alternate end pushes ("Z" strategy, [MWCNT]) that bring ``tube`` to ``goal``.

    Repeats, from the simulated pose, until both tolerances are met:

    1. if the centre is farther than ``position_tolerance`` from the goal: turn the axis
       perpendicular to the offset (skipped when the axial miss would stay below half the
       tolerance; within half a radian of the goal angle when the offset is shorter than L/4,
       so that small corrections need small turns), then translate sideways (a "Z");
    2. otherwise turn to the goal angle.

    Turns leave a small axial drift of the centre (higher order in the rotation per push); when
    a round does not shrink the position error by 30 %, the rotation per push is halved.

    Parameters
    ----------
    tube : Nanotube
    goal : Nanotube or (x, y, angle)
        Goal pose (metres, radians).
    tip_radius : float, metres
    position_tolerance : float, metres
    angle_tolerance : float, radians
        Compared modulo pi (a tube is symmetric) unless ``match_ends`` (then end B must end where
        the goal's end B is).
    end_margin : float
        Contact arc-length from the pushed end, as a fraction of L (0 < end_margin < 0.4).
    max_rotation : float, radians
        Largest rotation per push (as the tube turns the contact slides toward the end).
    clearance : float, metres, optional
        Distance the tip starts away from the tube; default ``max(tip_radius, diameter)``.
    max_pushes : int
        The plan stops (``converged=False``) after about this many pushes.
    match_ends : bool

    Returns
    -------
    PushPlan

    Raises
    ------
    ManipulationError
        On invalid tolerances or parameters.
    """
    if not isinstance(tube, Nanotube):
        raise ManipulationError(f"tube must be a Nanotube (got {type(tube).__name__})")
    if isinstance(goal, Nanotube):
        gx, gy, ga = goal.pose
    else:
        g = np.asarray(goal, dtype=np.float64).ravel()
        if g.size != 3 or not np.isfinite(g).all():
            raise ManipulationError(f"goal must be a Nanotube or (x, y, angle) (got {goal!r})")
        gx, gy, ga = (float(v) for v in g)
    R = float(tip_radius)
    if not (math.isfinite(R) and R >= 0.0):
        raise ManipulationError(f"tip_radius must be >= 0 m (got {tip_radius!r})")
    tol_p = float(position_tolerance)
    tol_a = float(angle_tolerance)
    if not (math.isfinite(tol_p) and tol_p > 0.0):
        raise ManipulationError(f"position_tolerance must be positive, in metres (got {position_tolerance!r})")
    if not (math.isfinite(tol_a) and tol_a > 0.0):
        raise ManipulationError(f"angle_tolerance must be positive, in radians (got {angle_tolerance!r})")
    if not 0.0 < end_margin < 0.4:
        raise ManipulationError(f"end_margin must be in (0, 0.4) of the length (got {end_margin!r})")
    if not 0.0 < max_rotation <= 0.5:
        raise ManipulationError(f"max_rotation must be in (0, 0.5] rad (got {max_rotation!r})")
    L = tube.length
    clear = max(R, tube.diameter) if clearance is None else float(clearance)
    if not (math.isfinite(clear) and clear > 0.0):
        raise ManipulationError(f"clearance must be positive, in metres (got {clearance!r})")

    l_b = L * (1.0 - end_margin)
    s_b = float(rotation_centre(l_b, L))
    lever = l_b - s_b  # a
    arm = 0.5 * L - s_b  # c
    rho = R + tube.radius
    near, deviation = 0.25, 0.5

    def angle_err(t: Nanotube) -> float:
        d = ga - t.angle
        return math.atan2(math.sin(d), math.cos(d)) if match_ends else _wrap_half(d)

    pushes: list[PlannedPush] = []
    # "rot": rotation per push; halved whenever a round fails to shrink the position error
    # (the turns' residual axial drift, about third order in it, then falls below the tolerance)
    state = {"tube": tube, "end": "B", "rot": max_rotation}

    def do_push(d: float) -> None:
        """Push the current end by d (signed along its normal); the ends alternate."""
        cur, end = state["tube"], state["end"]
        state["end"] = "A" if end == "B" else "B"
        if abs(d) < 1e-9 * rho:
            return
        c, s = math.cos(cur.angle), math.sin(cur.angle)
        nu = np.array([-s, c]) * math.copysign(1.0, d)
        t = cur.point_at(l_b if end == "B" else L - l_b)
        start = np.array([t[0] - nu[0] * (rho + clear), t[1] - nu[1] * (rho + clear), t[2]])
        disp = np.array([nu[0] * (clear + abs(d)), nu[1] * (clear + abs(d)), 0.0])
        new = push(cur, start, disp, R).tube
        pushes.append(PlannedPush(start, disp, end, cur, new))
        state["tube"] = new

    def sigma() -> float:
        return 1.0 if state["end"] == "B" else -1.0

    def turn(theta: float) -> None:
        n = max(1, math.ceil(abs(theta) / state["rot"] - 1e-12))
        phi = theta / n
        for k in range(n + 1):
            rot = 0.5 * phi if k in (0, n) else phi
            do_push(sigma() * lever * rot)

    def translate(dist_nu: float) -> None:
        n = max(1, math.ceil(abs(dist_nu) / (arm * state["rot"]) - 1e-12))
        h = dist_nu * lever / (2.0 * n * arm)
        for k in range(n + 1):
            do_push(h if k in (0, n) else 2.0 * h)

    while len(pushes) < max_pushes:
        cur = state["tube"]
        ex, ey = gx - cur.x, gy - cur.y
        dist = math.hypot(ex, ey)
        e_ang = angle_err(cur)
        if dist <= tol_p and abs(e_ang) <= tol_a:
            break
        if dist > tol_p:
            target = math.atan2(ey, ex) - 0.5 * math.pi  # axis perpendicular to the offset
            if dist < near * L:
                target = ga + max(-deviation, min(deviation, _wrap_half(target - ga)))
            d_theta = _wrap_half(target - cur.angle)
            if abs(d_theta) > math.asin(min(1.0, 0.5 * tol_p / dist)):
                turn(d_theta)
                cur = state["tube"]
            c, s = math.cos(cur.angle), math.sin(cur.angle)
            translate(-s * (gx - cur.x) + c * (gy - cur.y))
        else:
            turn(e_ang)
        after = state["tube"]
        if math.hypot(gx - after.x, gy - after.y) > max(tol_p, 0.7 * dist):
            state["rot"] = max(0.5 * state["rot"], 1e-3)
    cur = state["tube"]
    dist = math.hypot(gx - cur.x, gy - cur.y)
    e_ang = angle_err(cur)
    return PushPlan(pushes, cur, bool(dist <= tol_p and abs(e_ang) <= tol_a), dist, e_ang)
