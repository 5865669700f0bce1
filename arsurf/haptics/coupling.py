"""Master-slave couplings: direct (scaled force) and force-position (PI + P, seed 003 Fig. 4).

Both couplings are used in two phases per servo tick, so the collision sits between them::

    p = coupling.probe_position(x_m, buttons)           # where the probe is this tick
    f_probe = <collision, contact, force at p>           # N on the probe, from the sample
    F = coupling.hand_force(x_m, v_m, buttons, f_probe)  # N on the handle (then filter? safety!)

Sign conventions: ``f_probe`` is the force the sample exerts on the probe; ``F`` is the force the
device exerts on the hand. In steady contact both couplings render :math:`F = A_f \\odot f_{probe}`.

**Direct coupling**: :math:`p = p_0 + (x_m - x_0)/A_d` (:class:`~arsurf.haptics.scaling.PositionScaling`,
with clutch and limits) and :math:`F = A_f \\odot f_{probe}` (seed 001 Eq. 9-10).

**Force-position coupling** (seed 003 Fig. 4, after Bolopion et al. 2009), per axis. The slave
(the probe's positioner) is velocity-commanded, :math:`V_c = H_s(s) V_s` with
:math:`H_s(s) = 1/((1+\\tau_1 s)(1+\\tau_2 s))` (Eq. 15). The PI controller
:math:`C(s) = B_{fp} + K_{fp}/s` acts on the master-slave velocity error in master units, i.e. a
spring-damper on the position error:

.. math::

    e = x_m - A_d x_c - e_0, \\qquad
    F_c = K_{fp}\\, e + B_{fp}\\,(v_m - A_d \\hat v_c), \\qquad F = -F_c, \\qquad
    V_s = G_n \\left(\\frac{F_c}{A_f} + f_{probe}\\right),

with :math:`\\hat v_c` the slave velocity measured by backward difference of its sampled position
and :math:`e_0` the clutch offset. In free space the slave follows the master; on a stiff sample
the slave stops where :math:`F_c/A_f = -f_{probe}`, and the hand feels :math:`A_f f_{probe}`.
The slave's state is integrated exactly (ZOH) for the commanded :math:`V_s`.

**Admissible gains** (DESIGN.md's corrected Table II of seed 003), per axis, with master
:math:`H_m = 1/(B_v + M_v s)` and sampling period :math:`T_e`:

.. math::

    K_{fp} \\le \\frac{4M_v}{T_e^2}, \\qquad B_{fp} \\ge \\frac{K_{fp}T_e}{2} - B_v, \\qquad
    G_n \\le \\frac{A_f}{A_d K_{fp} T_e/2 + A_d B_{fp}} .

The same sampled-data analysis (Jury criterion at :math:`z=-1` for the loop above: master with
ZOH force, velocity-commanded slave) gives two more conditions, which :func:`check_gains` also
reports because the closed-loop simulation shows they matter:

.. math::

    B_{fp} \\le \\frac{2M_v}{T_e} - B_v \\quad(\\text{the table's } K_{fp} \\text{ bound is where this meets the } B_{fp} \\text{ lower bound}),

    \\frac{G_n A_d (B_{fp} + K_{fp}T_e/2)}{A_f} \\le \\left(1 - \\frac{G_n k_e T_e}{2}\\right)\\left(1 - \\frac{(B_{fp}+B_v)T_e}{2M_v}\\right)
    \\quad(\\text{joint}).

Derivation (damping :math:`B_v` neglected, it adds to :math:`B_{fp}` to first order). With the
force held over a tick, the master gives :math:`X_m = -\\frac{T_e^2}{2M_v}\\frac{z+1}{(z-1)^2}F_c`,
:math:`V_m = -\\frac{T_e}{M_v(z-1)}F_c`; the slave gives
:math:`A_d X_c = \\frac{g T_e}{z - 1 + G_n k_e T_e}F_c` with :math:`g = G_n A_d/A_f`, and the
loop closes through :math:`F_c = K_{fp}(X_m - A_d X_c) + B_{fp}(V_m - A_d X_c (1-z^{-1})/T_e)`:

.. math::

    1 + \\frac{K_{fp}T_e^2}{2M_v}\\frac{z+1}{(z-1)^2} + \\frac{B_{fp}T_e}{M_v(z-1)}
      + \\frac{g\\,\\big(K_{fp}T_e + B_{fp}(1-z^{-1})\\big)}{z-1+G_nk_eT_e} = 0 .

Master alone (:math:`g = 0`): :math:`z^2 + (K_{fp}T_e^2/2M_v + B_{fp}T_e/M_v - 2)z + 1 +
K_{fp}T_e^2/2M_v - B_{fp}T_e/M_v = 0`; Jury's conditions give :math:`B_{fp} > K_{fp}T_e/2` and
:math:`B_{fp} < 2M_v/T_e`, hence :math:`K_{fp} < 4M_v/T_e^2`. With the slave, the left side at
:math:`z = -1` (oscillation at half the sampling rate) is
:math:`1 - \\frac{B_{fp}T_e}{2M_v} - \\frac{g(B_{fp} + K_{fp}T_e/2)}{1 - G_nk_eT_e/2}`, which changes
sign on the joint bound. The master-side bounds are the worst case of a slave that does not
follow (stiff contact); in free space a fast slave relieves the master. Table II's :math:`G_n` bound is its limit for a master that does not move
(:math:`M_v \\to \\infty`) and a free slave (:math:`k_e = 0`); with a light master both loops share
the same margin and the slave gain must be lower. These bounds hold for slave time constants short
against :math:`T_e` (lags reduce the loop gain at :math:`z = -1`, so they stay conservative there);
:func:`simulate_force_position` measures the behaviour for any setting.

Example
-------
>>> g = suggest_gains(mass=1/300, damping=1/30, dt=1e-3, A_f=1e7, A_d=1e5)
>>> check_gains(**g, mass=1/300, damping=1/30, dt=1e-3, A_f=1e7, A_d=1e5).ok
True
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numba import njit

from arsurf.errors import HapticsError
from arsurf.haptics.device import BUTTON_1, _vec3
from arsurf.haptics.scaling import ForceScaling, PositionScaling
from arsurf.haptics.virtual_device import HandModel, VirtualDevice, discretize_zoh

__all__ = [
    "CLAMPED",
    "CLUTCHED",
    "NONFINITE",
    "Bound",
    "CouplingSimulation",
    "DirectCoupling",
    "ForcePositionCoupling",
    "GainCheck",
    "check_gains",
    "envelope_decay_ratio",
    "fp_step",
    "simulate_force_position",
    "suggest_gains",
]

CLUTCHED = 1  #: clutch held: slave frozen (no force, or the last one held)
CLAMPED = 2  #: slave clamped to the probe range
NONFINITE = 8  #: non-finite master state (no force, slave frozen) or probe force (slave frozen)

# params layout of ForcePositionCoupling (per axis blocks of 3)
_P_K, _P_B, _P_G, _P_AF, _P_AD, _P_LO, _P_HI = 0, 3, 6, 9, 12, 15, 18
_P_DT = 21
_P_HOLD = 22  # 1: hold the last force while the clutch is held (seed 003), 0: zero force (seed 001)
_NP = 23
# state layout: slave states (3 per axis: x, v, a), previous x, offset, flags
_S_SL = 0  # (3 axes x 3 states) = 9
_S_XPREV = 9
_S_OFF = 12
_S_CLUTCH = 15
_S_ANCHOR = 16
_S_FLAST = 17  # last force sent (3)
_NS = 20


@njit(cache=True)
def fp_step(params, phi, gamma, state, x_m, v_m, f_probe, clutched, force_out, probe_out):
    """One tick of the force-position coupling (module docstring); returns flags.

    ``params`` (23,), ``phi`` (3, 3, 3) and ``gamma`` (3, 3) slave ZOH matrices, ``state`` (20,)
    (updated), ``x_m``, ``v_m`` (3,) master position m and velocity m/s, ``f_probe`` (3,) N,
    ``clutched`` bool, ``force_out`` (3,) N on the handle, ``probe_out`` (3,) next probe position.
    """
    dt = params[_P_DT]
    flags = 0
    master_ok = True
    for j in range(3):
        if not (math.isfinite(x_m[j]) and math.isfinite(v_m[j])):
            master_ok = False
    probe_ok = math.isfinite(f_probe[0]) and math.isfinite(f_probe[1]) and math.isfinite(f_probe[2])
    if not master_ok or not probe_ok:
        flags |= NONFINITE
    if master_ok and state[_S_ANCHOR] == 0.0:
        for j in range(3):
            state[_S_OFF + j] = x_m[j] - params[_P_AD + j] * state[_S_SL + 3 * j]
            state[_S_XPREV + j] = state[_S_SL + 3 * j]
        state[_S_ANCHOR] = 1.0
    if clutched or not master_ok:
        # slave stopped where it is; no force (or the last one held while clutching, seed 003);
        # re-anchor on release
        hold = clutched and params[_P_HOLD] != 0.0
        if clutched:
            flags |= CLUTCHED
            state[_S_CLUTCH] = 1.0
        for j in range(3):
            force_out[j] = state[_S_FLAST + j] if hold else 0.0
            state[_S_FLAST + j] = force_out[j]
            x = state[_S_SL + 3 * j]
            state[_S_SL + 3 * j + 1] = 0.0
            state[_S_SL + 3 * j + 2] = 0.0
            state[_S_XPREV + j] = x
            probe_out[j] = x
        return flags
    if state[_S_CLUTCH] != 0.0:
        state[_S_CLUTCH] = 0.0
        for j in range(3):
            state[_S_OFF + j] = x_m[j] - params[_P_AD + j] * state[_S_SL + 3 * j]
    for j in range(3):
        ad = params[_P_AD + j]
        x = state[_S_SL + 3 * j]
        vc = (x - state[_S_XPREV + j]) / dt
        e = x_m[j] - ad * x - state[_S_OFF + j]
        fc = params[_P_K + j] * e + params[_P_B + j] * (v_m[j] - ad * vc)
        force_out[j] = 0.0 - fc  # (0 - fc, not -fc: no negative zero)
        state[_S_FLAST + j] = force_out[j]
        if probe_ok:
            vs = params[_P_G + j] * (fc / params[_P_AF + j] + f_probe[j])
        else:
            vs = 0.0
        s0 = state[_S_SL + 3 * j]
        s1 = state[_S_SL + 3 * j + 1]
        s2 = state[_S_SL + 3 * j + 2]
        for i in range(3):
            state[_S_SL + 3 * j + i] = phi[j, i, 0] * s0 + phi[j, i, 1] * s1 + phi[j, i, 2] * s2 + gamma[j, i] * vs
        xn = state[_S_SL + 3 * j]
        if xn < params[_P_LO + j] or xn > params[_P_HI + j]:
            xn = params[_P_LO + j] if xn < params[_P_LO + j] else params[_P_HI + j]
            state[_S_SL + 3 * j] = xn
            state[_S_SL + 3 * j + 1] = 0.0
            state[_S_SL + 3 * j + 2] = 0.0
            flags |= CLAMPED
        state[_S_XPREV + j] = x
        probe_out[j] = xn
    return flags


# ---------------------------------------------------------------------------------------------
# gain bounds
# ---------------------------------------------------------------------------------------------
_AXES = "xyz"


@dataclass(frozen=True)
class Bound:
    """One admissibility condition, per axis.

    Attributes
    ----------
    name : str
        ``K_fp_max``, ``B_fp_min``, ``G_n_max`` (Table II), ``B_fp_max``, ``joint`` (same analysis).
    relation : str
        ``"<="`` or ``">="``: ``value relation limit`` must hold.
    value, limit : (3,) float
        The gain (or, for ``joint``, the left-hand side) and its bound, per axis.
    ok : (3,) bool
    source : str
    """

    name: str
    relation: str
    value: np.ndarray
    limit: np.ndarray
    ok: np.ndarray
    source: str


@dataclass(frozen=True)
class GainCheck:
    """Result of :func:`check_gains`: whether a gain set is admissible and which bound fails."""

    bounds: tuple[Bound, ...]

    @property
    def ok(self) -> bool:
        """All bounds hold on every axis."""
        return all(bool(b.ok.all()) for b in self.bounds)

    @property
    def table_ok(self) -> bool:
        """The three bounds of (corrected) Table II hold on every axis."""
        return all(bool(b.ok.all()) for b in self.bounds if b.name in ("K_fp_max", "B_fp_min", "G_n_max"))

    @property
    def failed(self) -> list[str]:
        """Failed bounds as ``"name (axis)"``, e.g. ``["G_n_max (x)"]``."""
        return [f"{b.name} ({_AXES[i]})" for b in self.bounds for i in range(3) if not b.ok[i]]

    def bound(self, name: str) -> Bound:
        for b in self.bounds:
            if b.name == name:
                return b
        raise KeyError(name)

    def __str__(self) -> str:
        if self.ok:
            return "gains admissible (Table II and joint Nyquist condition hold on every axis)"
        parts = []
        for b in self.bounds:
            for i in range(3):
                if not b.ok[i]:
                    parts.append(f"{b.name} ({_AXES[i]}): {b.value[i]:.6g} {b.relation} {b.limit[i]:.6g} fails")
        return "gains not admissible: " + "; ".join(parts)


def _gain_arrays(K_fp, B_fp, G_n, A_f, A_d, mass, damping, dt, env_stiffness):
    K = _vec3(K_fp, "K_fp")
    B = _vec3(B_fp, "B_fp")
    G = _vec3(G_n, "G_n")
    Af = _vec3(A_f, "A_f")
    Ad = _vec3(A_d, "A_d")
    M = _vec3(mass, "mass (M_v)")
    Bv = _vec3(damping, "damping (B_v)")
    ke = _vec3(env_stiffness, "env_stiffness (k_e)")
    if (K < 0).any() or (B < 0).any():
        raise HapticsError(f"K_fp and B_fp must be >= 0 (got K_fp {K.tolist()} N/m, B_fp {B.tolist()} N s/m)")
    if (G <= 0).any():
        raise HapticsError(f"G_n must be positive (got {G.tolist()} m/(N s)); it is the slave's velocity per newton")
    if (Af <= 0).any() or (Ad <= 0).any():
        raise HapticsError(f"A_f and A_d must be positive scale factors (got A_f {Af.tolist()}, A_d {Ad.tolist()})")
    if (M <= 0).any() or (Bv < 0).any():
        raise HapticsError(f"mass must be positive and damping >= 0 (got M_v {M.tolist()} kg, B_v {Bv.tolist()} N s/m)")
    if (ke < 0).any():
        raise HapticsError(f"env_stiffness must be >= 0 (got {ke.tolist()} N/m)")
    try:
        T = float(dt)
    except (TypeError, ValueError) as exc:
        raise HapticsError(f"dt must be the sampling period T_e in seconds (got {dt!r})") from exc
    if not (T > 0 and math.isfinite(T)):
        raise HapticsError(f"dt must be the sampling period T_e in seconds, positive (got {dt!r})")
    return K, B, G, Af, Ad, M, Bv, T, ke


def check_gains(K_fp, B_fp, G_n, *, A_f, A_d, mass, damping, dt, env_stiffness=0.0) -> GainCheck:
    """Check force-position gains against the admissible ranges (corrected Table II + joint).

    Parameters
    ----------
    K_fp : float or (3,), N/m
        Integral gain of the PI controller (the rendered stiffness).
    B_fp : float or (3,), N s/m
        Proportional gain (virtual damping).
    G_n : float or (3,), m/(N s)
        Slave P gain (slave velocity per newton of force error, slave units).
    A_f, A_d : float or (3,)
        Force up-scaling and position down-scaling factors.
    mass, damping : float or (3,)
        Master :math:`M_v` (kg) and :math:`B_v` (N s/m), :math:`H_m = 1/(B_v + M_v s)`.
    dt : float, s
        Sampling period :math:`T_e`.
    env_stiffness : float or (3,), N/m
        Environment stiffness :math:`k_e` on the slave side (0: free space).

    Returns
    -------
    GainCheck
        ``ok``, ``table_ok``, ``failed`` and the five :class:`Bound` records.

    Example
    -------
    >>> c = check_gains(100.0, 0.1, 825.0, A_f=25e6, A_d=50e3, mass=0.5, damping=0.2, dt=5e-3)
    >>> c.ok, round(float(c.bound("G_n_max").limit[0]), 2)      # seed 003, Fig. 5 (x axis)
    (True, 1428.57)
    >>> check_gains(100.0, 0.1, 2000.0, A_f=25e6, A_d=50e3, mass=0.5, damping=0.2, dt=5e-3).failed[:1]
    ['G_n_max (x)']
    """
    K, B, G, Af, Ad, M, Bv, T, ke = _gain_arrays(K_fp, B_fp, G_n, A_f, A_d, mass, damping, dt, env_stiffness)
    table = "seed 003 Table II as corrected in DESIGN.md"
    derived = "same sampled-data analysis (Jury criterion at z = -1), arsurf.haptics.coupling"
    k_max = 4.0 * M / T**2
    b_min = K * T / 2.0 - Bv
    g_max = Af / (Ad * K * T / 2.0 + Ad * B)
    b_max = 2.0 * M / T - Bv
    lhs = G * Ad * (B + K * T / 2.0) / Af
    rhs = (1.0 - G * ke * T / 2.0) * (1.0 - (B + Bv) * T / (2.0 * M))
    bounds = (
        Bound("K_fp_max", "<=", K, k_max, K <= k_max, table),
        Bound("B_fp_min", ">=", B, b_min, B >= b_min, table),
        Bound("G_n_max", "<=", G, g_max, G <= g_max, table),
        Bound("B_fp_max", "<=", B, b_max, B <= b_max, derived),
        Bound("joint", "<=", lhs, rhs, (lhs <= rhs) & (rhs > 0), derived),
    )
    for b in bounds:
        for a in ("value", "limit", "ok"):
            getattr(b, a).setflags(write=False)
    return GainCheck(bounds)


def suggest_gains(*, mass, damping, dt, A_f, A_d, env_stiffness=0.0, stiffness: float = 0.25,
                  slave_margin: float = 0.5) -> dict[str, np.ndarray]:
    """A gain set inside the admissible region, as a dict ``K_fp``, ``B_fp``, ``G_n`` ((3,) each).

    :math:`K_{fp}` = ``stiffness`` :math:`\\times 4M_v/T_e^2`; :math:`B_{fp}` the middle of
    :math:`[K_{fp}T_e/2 - B_v,\\ 2M_v/T_e - B_v]` (at least 0); :math:`G_n` = ``slave_margin``
    times the largest value the joint condition and Table II allow.

    Example
    -------
    >>> g = suggest_gains(mass=0.05, damping=0.5, dt=1e-3, A_f=1e7, A_d=1e5)
    >>> round(float(g["K_fp"][0])), round(float(g["B_fp"][0]), 2)
    (50000, 62.0)
    """
    if not (0.0 < stiffness < 1.0):
        raise HapticsError(f"stiffness must be a fraction of 4 M_v / T_e^2 in (0, 1) (got {stiffness!r})")
    if not (0.0 < slave_margin < 1.0):
        raise HapticsError(f"slave_margin must be in (0, 1) (got {slave_margin!r})")
    _, _, _, Af, Ad, M, Bv, T, ke = _gain_arrays(0.0, 0.0, 1.0, A_f, A_d, mass, damping, dt, env_stiffness)
    K = stiffness * 4.0 * M / T**2
    b_lo = np.maximum(K * T / 2.0 - Bv, 0.0)
    b_hi = 2.0 * M / T - Bv
    if (b_hi <= b_lo).any():
        raise HapticsError(
            f"no admissible damping: B_fp must lie in [{b_lo.tolist()}, {b_hi.tolist()}] N s/m; "
            "the master damping B_v is too large for this rate, lower dt"
        )
    B = 0.5 * (b_lo + b_hi)
    m = 1.0 - (B + Bv) * T / (2.0 * M)
    a = Ad * (B + K * T / 2.0) / Af
    g_joint = m / (a + m * ke * T / 2.0)  # solves a G = (1 - G ke T/2) m
    g_table = Af / (Ad * (K * T / 2.0 + B))
    G = slave_margin * np.minimum(g_joint, g_table)
    return {"K_fp": K, "B_fp": B, "G_n": G}


# ---------------------------------------------------------------------------------------------
# couplings
# ---------------------------------------------------------------------------------------------
class DirectCoupling:
    """Direct coupling: the probe follows the scaled master, the hand feels the scaled force.

    Parameters
    ----------
    position : PositionScaling
        Master -> probe map (scale, clutch, limits).
    force : ForceScaling
        Probe -> hand force scale (:math:`K_f` or per-axis :math:`A_f`).

    Example
    -------
    >>> c = DirectCoupling(PositionScaling(1e-5), ForceScaling(1e7))
    >>> (c.probe_position([0.01, 0, 0]) * 1e9).round(6).tolist()
    [100.0, 0.0, 0.0]
    >>> c.hand_force([0.01, 0, 0], [0, 0, 0], 0, [-1e-7, 0, 0]).tolist()
    [-1.0, 0.0, 0.0]
    """

    def __init__(self, position: PositionScaling, force: ForceScaling) -> None:
        if not isinstance(position, PositionScaling) or not isinstance(force, ForceScaling):
            raise HapticsError("DirectCoupling needs a PositionScaling and a ForceScaling")
        self.position = position
        self.force = force
        self.flags = 0

    def probe_position(self, master_position, buttons: int = 0, out=None) -> np.ndarray:
        """Probe position (3,) m for this tick (clutch and limits applied)."""
        p = self.position.map(master_position, buttons, out)
        self.flags = self.position.flags
        return p

    def hand_force(self, master_position, master_velocity, buttons: int, probe_force, out=None) -> np.ndarray:
        """Hand force (3,) N: :math:`A_f \\odot f_{probe}`."""
        f = self.force.apply(probe_force, out)
        self.flags = self.force.flags
        return f


class ForcePositionCoupling:
    """Force-position coupling (PI on the master, P on the slave), seed 003 Fig. 4.

    Parameters
    ----------
    K_fp, B_fp, G_n : float or (3,)
        PI integral gain (N/m), PI proportional gain (N s/m), slave gain (m/(N s)).
    A_f, A_d : float or (3,)
        Force and position scale factors.
    dt : float, s
        Sampling period :math:`T_e`.
    slave_tau : (tau1, tau2), s
        Time constants of :math:`H_s` (0 for an ideal velocity-controlled slave, the default).
    probe_origin : (3,) float, m
        Initial slave (probe) position.
    probe_limits : None or (lower (3,), upper (3,)), m
        Slave range; the slave is clamped to it.
    clutch_mask : int
        Buttons that hold the clutch (slave frozen, re-anchor on release).
    hold_force_on_clutch : bool
        While clutching, keep rendering the last force (seed 003: "the force sent back to the user
        is constant during this operation") instead of none (default; seed 001: the button
        "temporarily disables the force").
    mass, damping : float or (3,), optional
        Master :math:`M_v`, :math:`B_v`; when given (and ``check``), the gains are checked with
        :func:`check_gains` and refused if not admissible.
    env_stiffness : float or (3,), N/m
        Expected environment stiffness, for the check.
    check : bool
        Refuse inadmissible gains (default True); False lets a simulation show what happens.

    Attributes
    ----------
    params, phi, gamma, state : float64 arrays
        Arguments of :func:`fp_step` for a compiled tick.

    Example
    -------
    >>> c = ForcePositionCoupling(K_fp=3000.0, B_fp=4.0, G_n=5.0, A_f=1e7, A_d=1e5, dt=1e-3,
    ...                           mass=1/300, damping=1/30)
    >>> c.probe_position().tolist()
    [0.0, 0.0, 0.0]
    >>> c.hand_force([1e-3, 0, 0], [0, 0, 0], 0, [0, 0, 0]).tolist()   # first call anchors: no jolt
    [0.0, 0.0, 0.0]
    """

    def __init__(self, K_fp, B_fp, G_n, *, A_f, A_d, dt: float, slave_tau=(0.0, 0.0),
                 probe_origin=(0.0, 0.0, 0.0), probe_limits=None, clutch_mask: int = BUTTON_1,
                 hold_force_on_clutch: bool = False, mass=None, damping=None, env_stiffness=0.0,
                 check: bool = True) -> None:
        m_chk = 1.0 if mass is None else mass
        b_chk = 0.0 if damping is None else damping
        K, B, G, Af, Ad, M, Bv, T, ke = _gain_arrays(K_fp, B_fp, G_n, A_f, A_d, m_chk, b_chk, dt, env_stiffness)
        if (mass is None) != (damping is None):
            raise HapticsError("give both mass and damping of the master (or neither)")
        self.gain_check = None
        if mass is not None:
            self.gain_check = check_gains(K, B, G, A_f=Af, A_d=Ad, mass=M, damping=Bv, dt=T, env_stiffness=ke)
            if check and not self.gain_check.ok:
                raise HapticsError(
                    f"{self.gain_check}; lower K_fp or G_n, move B_fp into its range "
                    "(suggest_gains() gives an admissible set), or pass check=False to simulate anyway"
                )
        try:
            t1, t2 = (float(v) for v in slave_tau)
        except (TypeError, ValueError) as exc:
            raise HapticsError(f"slave_tau must be a pair (tau1, tau2) in seconds (got {slave_tau!r})") from exc
        if not (t1 >= 0 and t2 >= 0 and math.isfinite(t1) and math.isfinite(t2)):
            raise HapticsError(f"slave time constants must be >= 0 and finite (got {slave_tau!r} s)")
        if t1 < t2:
            t1, t2 = t2, t1
        self.slave_tau = (t1, t2)
        self.dt = T
        self.phi, self.gamma = self._slave_matrices(t1, t2, T)
        p = np.zeros(_NP)
        p[_P_K:_P_K + 3] = K
        p[_P_B:_P_B + 3] = B
        p[_P_G:_P_G + 3] = G
        p[_P_AF:_P_AF + 3] = Af
        p[_P_AD:_P_AD + 3] = Ad
        if probe_limits is None:
            p[_P_LO:_P_LO + 3] = -np.inf
            p[_P_HI:_P_HI + 3] = np.inf
        else:
            try:
                lo, hi = probe_limits
            except (TypeError, ValueError) as exc:
                raise HapticsError("probe_limits must be None or (lower (3,), upper (3,)) in metres") from exc
            lo, hi = _vec3(lo, "probe_limits lower"), _vec3(hi, "probe_limits upper")
            if not (lo < hi).all():
                raise HapticsError(f"probe_limits lower must be below upper (got {lo.tolist()}, {hi.tolist()})")
            p[_P_LO:_P_LO + 3] = lo
            p[_P_HI:_P_HI + 3] = hi
        p[_P_DT] = T
        p[_P_HOLD] = 1.0 if hold_force_on_clutch else 0.0
        self.params = p
        if not isinstance(clutch_mask, (int, np.integer)) or clutch_mask < 0:
            raise HapticsError(f"clutch_mask must be a non-negative button bitmask (got {clutch_mask!r})")
        self.clutch_mask = int(clutch_mask)
        self.state = np.zeros(_NS)
        self._force = np.zeros(3)
        self._probe = np.zeros(3)
        self.flags = 0
        self.reset(probe_origin)

    @staticmethod
    def _slave_matrices(t1: float, t2: float, T: float) -> tuple[np.ndarray, np.ndarray]:
        """ZOH matrices of the slave (x, v, a) for V_s -> x with H_s = 1/((1+t1 s)(1+t2 s))."""
        phi = np.zeros((3, 3, 3))
        gamma = np.zeros((3, 3))
        if t1 == 0.0:  # ideal: v = V_s
            P = np.zeros((3, 3))
            P[0, 0] = 1.0
            G = np.array([T, 1.0, 0.0])
        elif t2 == 0.0:  # first order
            A = np.array([[0.0, 1.0], [0.0, -1.0 / t1]])
            Bm = np.array([[0.0], [1.0 / t1]])
            P2, G2 = discretize_zoh(A, Bm, T)
            P = np.zeros((3, 3))
            P[:2, :2] = P2
            G = np.array([G2[0, 0], G2[1, 0], 0.0])
        else:
            A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0 / (t1 * t2), -(t1 + t2) / (t1 * t2)]])
            Bm = np.array([[0.0], [0.0], [1.0 / (t1 * t2)]])
            P, G2 = discretize_zoh(A, Bm, T)
            G = G2[:, 0]
        for j in range(3):
            phi[j] = P
            gamma[j] = G
        return phi, gamma

    @property
    def gains(self) -> dict[str, np.ndarray]:
        p = self.params
        return {"K_fp": p[_P_K:_P_K + 3].copy(), "B_fp": p[_P_B:_P_B + 3].copy(), "G_n": p[_P_G:_P_G + 3].copy()}

    def reset(self, probe_position=(0.0, 0.0, 0.0)) -> None:
        """Slave at rest at ``probe_position`` (m); the next :meth:`hand_force` re-anchors the master."""
        p = _vec3(probe_position, "probe_position")
        self.state[:] = 0.0
        for j in range(3):
            self.state[_S_SL + 3 * j] = p[j]
            self.state[_S_XPREV + j] = p[j]
        self._probe[:] = p

    def probe_position(self, master_position=None, buttons: int = 0, out=None) -> np.ndarray:
        """The slave (probe) position (3,) m this tick (the master does not move it within a tick)."""
        o = self._probe if out is None else out
        for j in range(3):
            o[j] = self.state[_S_SL + 3 * j]
        return o.copy() if out is None else o

    def hand_force(self, master_position, master_velocity, buttons: int, probe_force, out=None) -> np.ndarray:
        """Hand force (3,) N for this tick; advances the slave by one period."""
        x = np.asarray(master_position, dtype=np.float64)
        v = np.asarray(master_velocity, dtype=np.float64)
        f = np.asarray(probe_force, dtype=np.float64)
        if x.shape != (3,) or v.shape != (3,) or f.shape != (3,):
            raise HapticsError(
                f"master_position, master_velocity and probe_force must have shape (3,) (got {x.shape}, {v.shape}, {f.shape})"
            )
        o = self._force if out is None else out
        self.flags = fp_step(self.params, self.phi, self.gamma, self.state, x, v, f,
                             (int(buttons) & self.clutch_mask) != 0, o, self._probe)
        return o.copy() if out is None else o

    def coupling_error(self, master_position) -> np.ndarray:
        """Position error :math:`e = x_m - A_d x_c - e_0` in master metres, (3,)."""
        x = _vec3(master_position, "master_position")
        xc = self.state[_S_SL:_S_SL + 9:3]
        return x - self.params[_P_AD:_P_AD + 3] * xc - self.state[_S_OFF:_S_OFF + 3]


# ---------------------------------------------------------------------------------------------
# closed-loop simulation
# ---------------------------------------------------------------------------------------------
_DIVERGED = 1e6  # m or N: far outside anything physical, the simulation stops


def envelope_decay_ratio(signal, window: float = 0.2) -> float:
    """How the oscillation envelope of ``signal`` evolves: late envelope / early envelope.

    The envelope is the largest tick-to-tick change :math:`|s_k - s_{k-1}|` in a window (a
    constant offset does not count; a steady drift gives 1); the ratio compares the last ``window``
    fraction of the record with the first. Below 1: the motion dies out (stable rendering); about 1:
    sustained oscillation; above 1: growth. ``inf`` if the record is not finite.

    Example
    -------
    >>> k = np.arange(2000)
    >>> round(envelope_decay_ratio(np.exp(-k / 200) * np.cos(0.3 * k)), 4)
    0.0003
    """
    s = np.asarray(signal, dtype=np.float64)
    if s.ndim != 1 or s.size < 10:
        raise HapticsError(f"signal must be 1-D with at least 10 samples (got shape {s.shape})")
    if not (0.0 < window <= 0.5):
        raise HapticsError(f"window must be a fraction in (0, 0.5] (got {window!r})")
    if not np.isfinite(s).all():
        return math.inf
    d = np.abs(np.diff(s))
    w = max(1, int(window * d.size))
    early = d[:w].max()
    late = d[-w:].max()
    if early == 0.0:
        return 0.0 if late == 0.0 else math.inf
    return float(late / early)


@dataclass(frozen=True)
class CouplingSimulation:
    """Record of :func:`simulate_force_position` (arrays over ticks, SI units).

    Attributes
    ----------
    t : (n,) s
    master : (n, 3) m, master position
    probe : (n, 3) m, slave position
    force : (n, 3) N, force on the handle
    probe_force : (n, 3) N, environment force on the probe
    error : (n, 3) m, coupling error :math:`x_m - A_d x_c - e_0`
    diverged : bool
        The run stopped early because the state left any physical range (1e6 m or N): the
        record ends there, and :meth:`decay_ratio` measures the growth up to that point.
    """

    t: np.ndarray
    master: np.ndarray
    probe: np.ndarray
    force: np.ndarray
    probe_force: np.ndarray
    error: np.ndarray
    diverged: bool

    def decay_ratio(self, axis: int = 0, window: float = 0.2) -> float:
        """:func:`envelope_decay_ratio` of the coupling error on ``axis`` over the record.

        For a diverged run the record stops at the divergence, so the ratio measures the growth
        (``inf`` if fewer than 10 ticks were recorded).
        """
        e = self.error[:, axis]
        if e.size < 10:
            return math.inf
        return envelope_decay_ratio(e, window)

    def oscillation_frequency(self, axis: int = 0) -> float:
        """Dominant frequency (Hz) of the tick-to-tick error changes over the last half of the run."""
        d = np.diff(self.error[:, axis])
        d = d[d.size // 2:]
        d = d[np.isfinite(d)]
        if d.size < 4:
            return math.nan
        spec = np.abs(np.fft.rfft(d - d.mean()))
        freqs = np.fft.rfftfreq(d.size, self.t[1] - self.t[0])
        return float(freqs[int(np.argmax(spec))])


def simulate_force_position(coupling: ForcePositionCoupling, *, mass, damping, env_stiffness=0.0,
                            wall: float = 0.0, unilateral: bool = True, push=0.5,
                            hand: HandModel | None = None, duration: float = 2.0) -> CouplingSimulation:
    """Closed-loop simulation: virtual master + force-position coupling + slave + environment.

    The master is a :class:`~arsurf.haptics.virtual_device.VirtualDevice` (mass ``mass``, damping
    ``damping``, exact ZOH per tick, no force saturation so the loop stays linear) pushed by the
    operator force ``push``; the slave is the coupling's own :math:`H_s`; the environment is a
    spring of stiffness ``env_stiffness`` along x at ``wall`` (slave units),

    .. math:: f_{probe,x} = -k_e\\,(x_c - x_{wall}) \\quad (\\text{only for } x_c > x_{wall} \\text{ if unilateral}).

    Parameters
    ----------
    coupling : ForcePositionCoupling
        Reset to its current probe position at the start; ``dt`` is its period.
    mass, damping : float or (3,)
        Master :math:`M_v` (kg), :math:`B_v` (N s/m).
    env_stiffness : float, N/m
    wall : float, m
    unilateral : bool
    push : float, (3,) or callable
        Operator force on the stylus, N: a constant along x, a constant vector, or ``t -> (3,)``.
    hand : HandModel, optional
        A grip on the stylus as well (default none: only ``push``).
    duration : float, s

    Returns
    -------
    CouplingSimulation

    Example
    -------
    >>> g = suggest_gains(mass=1/300, damping=1/30, dt=1e-3, A_f=1e7, A_d=1e5, env_stiffness=10.0)
    >>> c = ForcePositionCoupling(**g, A_f=1e7, A_d=1e5, dt=1e-3, slave_tau=(1e-4, 2e-5))
    >>> sim = simulate_force_position(c, mass=1/300, damping=1/30, env_stiffness=10.0, duration=1.0)
    >>> sim.decay_ratio() < 1e-3, round(float(sim.force[-1, 0]), 3)     # settles at -push
    (True, -0.5)
    """
    if not isinstance(coupling, ForcePositionCoupling):
        raise HapticsError(f"coupling must be a ForcePositionCoupling (got {type(coupling).__name__})")
    dt = coupling.dt
    duration = float(duration)
    if not (duration > 10 * dt and math.isfinite(duration)):
        raise HapticsError(f"duration must be longer than 10 ticks ({10 * dt:g} s) (got {duration!r})")
    ke = float(env_stiffness)
    if not (ke >= 0.0 and math.isfinite(ke)):
        raise HapticsError(f"env_stiffness must be >= 0 N/m (got {env_stiffness!r})")
    if callable(push):
        ext: Callable = push
    else:
        pv = np.asarray(push, dtype=np.float64)
        pvec = np.array([float(pv), 0.0, 0.0]) if pv.ndim == 0 else _vec3(pv, "push")

        def ext(t, _p=pvec):
            return _p
    dev = VirtualDevice(dt=dt, mass=mass, damping=damping, hand=hand, external_force=ext, max_force=np.inf)
    coupling.reset(coupling.probe_position())
    n = int(round(duration / dt))
    t = np.arange(n) * dt
    xm = np.full((n, 3), np.nan)
    xc = np.full((n, 3), np.nan)
    fh = np.full((n, 3), np.nan)
    fe = np.full((n, 3), np.nan)
    err = np.full((n, 3), np.nan)
    st = None
    f_probe = np.zeros(3)
    force = np.zeros(3)
    diverged = False
    with dev:
        for k in range(n):
            st = dev.read_state(st)
            p = coupling.probe_position()
            pen = p[0] - wall
            f_probe[0] = -ke * pen if (pen > 0.0 or not unilateral) else 0.0
            coupling.hand_force(st.position, st.velocity, st.buttons, f_probe, out=force)
            xm[k] = st.position
            xc[k] = p
            fh[k] = force
            fe[k] = f_probe
            err[k] = coupling.coupling_error(st.position)
            if not (np.abs(st.position).max() < _DIVERGED and np.abs(force).max() < _DIVERGED
                    and np.isfinite(err[k]).all() and np.abs(err[k]).max() < _DIVERGED):
                diverged = True
                n = k + 1
                break
            dev.command_force(force)
    return CouplingSimulation(t[:n], xm[:n], xc[:n], fh[:n], fe[:n], err[:n], diverged)
