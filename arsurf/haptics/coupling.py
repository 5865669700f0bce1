"""Master-slave couplings: direct (scaled force) and force-position (PI + P, [Bolopion] Fig. 4).

Both couplings are used in two phases per servo tick, so the collision sits between them::

    p = coupling.probe_position(x_m, buttons)           # where the probe is this tick
    f_probe = <collision, contact, force at p>           # N on the probe, from the sample
    F = coupling.hand_force(x_m, v_m, buttons, f_probe)  # N on the handle (then filter? safety!)

Sign conventions: ``f_probe`` is the force the sample exerts on the probe; ``F`` is the force the
device exerts on the hand. In steady contact both couplings render :math:`F = A_f \\odot f_{probe}`.

**Direct coupling**: :math:`p = p_0 + (x_m - x_0)/A_d` (:class:`~arsurf.haptics.scaling.PositionScaling`,
with clutch and limits) and :math:`F = A_f \\odot f_{probe}` ([Alabdulmuhsin] Eq. 9-10).

**Force-position coupling** ([Bolopion] Fig. 4, after Bolopion et al. 2009), per axis. The slave
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

The admissible gains of the force-position coupling are checked in :mod:`arsurf.haptics.gains`;
its closed-loop behaviour is simulated in :mod:`arsurf.haptics.coupling_simulation`.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from arsurf import status
from arsurf._layout import Layout
from arsurf.errors import HapticsError
from arsurf.haptics.device import BUTTON_1, _vec3
from arsurf.haptics.scaling import ForceScaling, PositionScaling
from arsurf.haptics.virtual_device import discretize_zoh

from arsurf.haptics.gains import _gain_arrays, check_gains

__all__ = [
    "CLAMPED",
    "CLUTCHED",
    "NONFINITE",
    "FP_PARAMS",
    "FP_STATE",
    "DirectCoupling",
    "ForcePositionCoupling",
    "fp_step",
]

CLUTCHED = status.CLUTCHED  #: clutch held: slave frozen (no force, or the last one held)
CLAMPED = status.CLAMPED  #: slave clamped to the probe range
NONFINITE = status.NONFINITE  #: non-finite master state (no force, slave frozen) or probe force (slave frozen)

#: the parameters of :func:`fp_step` (per-axis fields of 3): K_fp (N/m), B_fp (N s/m), G_n
#: (m/(N s)), A_f, A_d, the probe range (m), the period (s), and 1 to hold the last force while the
#: clutch is held ([Bolopion]), 0 for no force ([Alabdulmuhsin])
FP_PARAMS = Layout("force-position parameters", [
    ("stiffness", 3), ("damping", 3), ("slave_gain", 3), ("force_scale", 3), ("position_scale", 3),
    ("probe_lower", 3), ("probe_upper", 3), ("dt", 1), ("hold_force", 1)])
#: the state of :func:`fp_step`: the slave's (x, v, a) per axis, its previous x (m), the clutch
#: offset e_0 (master m), clutch held, anchored (0 or 1), the last force sent (N)
FP_STATE = Layout("force-position state", [
    ("slave", 9), ("previous_x", 3), ("offset", 3), ("clutched", 1), ("anchored", 1), ("last_force", 3)])
# the offsets as the kernel uses them
_P_K, _P_B, _P_G = FP_PARAMS.offset("stiffness"), FP_PARAMS.offset("damping"), FP_PARAMS.offset("slave_gain")
_P_AF, _P_AD = FP_PARAMS.offset("force_scale"), FP_PARAMS.offset("position_scale")
_P_LO, _P_HI = FP_PARAMS.offset("probe_lower"), FP_PARAMS.offset("probe_upper")
_P_DT, _P_HOLD = FP_PARAMS.offset("dt"), FP_PARAMS.offset("hold_force")
_S_SL, _S_XPREV, _S_OFF = FP_STATE.offset("slave"), FP_STATE.offset("previous_x"), FP_STATE.offset("offset")
_S_CLUTCH, _S_ANCHOR, _S_FLAST = FP_STATE.offset("clutched"), FP_STATE.offset("anchored"), FP_STATE.offset("last_force")


@njit(cache=True)
def fp_step(params, phi, gamma, state, x_m, v_m, f_probe, clutched, force_out, probe_out):
    """One tick of the force-position coupling (module docstring); returns flags.

    ``params`` (:data:`FP_PARAMS`), ``phi`` (3, 3, 3) and ``gamma`` (3, 3) slave ZOH matrices,
    ``state`` (:data:`FP_STATE`, updated), ``x_m``, ``v_m`` (3,) master position m and velocity m/s, ``f_probe`` (3,) N,
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
        # slave stopped where it is; no force (or the last one held while clutching, [Bolopion]);
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

    Examples
    --------
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

    def energy_gain(self) -> float:
        """Hand energy per probe energy, :math:`\\max K_f / \\min s` (J/J): a probe force
        :math:`f` over a probe path :math:`dx` is :math:`K_f f` over :math:`dx/s` at the hand."""
        return float(np.max(np.abs(self.force.gain)) / np.min(np.abs(self.position.scale)))

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
    """Force-position coupling (PI on the master, P on the slave), [Bolopion] Fig. 4.

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
        While clutching, keep rendering the last force ([Bolopion]: "the force sent back to the user
        is constant during this operation") instead of none (default; [Alabdulmuhsin]: the button
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

    Examples
    --------
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
        p = FP_PARAMS.zeros()
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
        self.state = FP_STATE.zeros()
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

    def energy_gain(self) -> float:
        """Hand energy per probe energy, :math:`\\max A_f A_d` (J/J): the hand feels
        :math:`A_f f` over :math:`A_d\\,dx`."""
        return float(np.max(self.params[_P_AF:_P_AF + 3] * self.params[_P_AD:_P_AD + 3]))

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
