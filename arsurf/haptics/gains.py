r"""Admissible gains of the force-position coupling ([Bolopion] Table II, corrected).

**Admissible gains** (the corrected Table II of [Bolopion]: docs/design.rst, "Known errors in the
sources"), per axis, with master
:math:`H_m = 1/(B_v + M_v s)` and sampling period :math:`T_e`:

.. math::

    K_{fp} \le \frac{4M_v}{T_e^2}, \qquad B_{fp} \ge \frac{K_{fp}T_e}{2} - B_v, \qquad
    G_n \le \frac{A_f}{A_d K_{fp} T_e/2 + A_d B_{fp}} .

The same sampled-data analysis (Jury criterion at :math:`z=-1` for the loop above: master with
ZOH force, velocity-commanded slave) gives two more conditions, which :func:`check_gains` also
reports because the closed-loop simulation shows they matter:

.. math::

    B_{fp} \le \frac{2M_v}{T_e} - B_v \quad(\text{the table's } K_{fp} \text{ bound is where this meets the } B_{fp} \text{ lower bound}),

    \frac{G_n A_d (B_{fp} + K_{fp}T_e/2)}{A_f} \le \left(1 - \frac{G_n k_e T_e}{2}\right)\left(1 - \frac{(B_{fp}+B_v)T_e}{2M_v}\right)
    \quad(\text{joint}).

Derivation (damping :math:`B_v` neglected, it adds to :math:`B_{fp}` to first order). With the
force held over a tick, the master gives :math:`X_m = -\frac{T_e^2}{2M_v}\frac{z+1}{(z-1)^2}F_c`,
:math:`V_m = -\frac{T_e}{M_v(z-1)}F_c`; the slave gives
:math:`A_d X_c = \frac{g T_e}{z - 1 + G_n k_e T_e}F_c` with :math:`g = G_n A_d/A_f`, and the
loop closes through :math:`F_c = K_{fp}(X_m - A_d X_c) + B_{fp}(V_m - A_d X_c (1-z^{-1})/T_e)`:

.. math::

    1 + \frac{K_{fp}T_e^2}{2M_v}\frac{z+1}{(z-1)^2} + \frac{B_{fp}T_e}{M_v(z-1)}
      + \frac{g\,\big(K_{fp}T_e + B_{fp}(1-z^{-1})\big)}{z-1+G_nk_eT_e} = 0 .

Master alone (:math:`g = 0`): :math:`z^2 + (K_{fp}T_e^2/2M_v + B_{fp}T_e/M_v - 2)z + 1 +
K_{fp}T_e^2/2M_v - B_{fp}T_e/M_v = 0`; Jury's conditions give :math:`B_{fp} > K_{fp}T_e/2` and
:math:`B_{fp} < 2M_v/T_e`, hence :math:`K_{fp} < 4M_v/T_e^2`. With the slave, the left side at
:math:`z = -1` (oscillation at half the sampling rate) is
:math:`1 - \frac{B_{fp}T_e}{2M_v} - \frac{g(B_{fp} + K_{fp}T_e/2)}{1 - G_nk_eT_e/2}`, which changes
sign on the joint bound. The master-side bounds are the worst case of a slave that does not
follow (stiff contact); in free space a fast slave relieves the master. Table II's :math:`G_n` bound is its limit for a master that does not move
(:math:`M_v \to \infty`) and a free slave (:math:`k_e = 0`); with a light master both loops share
the same margin and the slave gain must be lower. These bounds hold for slave time constants short
against :math:`T_e` (lags reduce the loop gain at :math:`z = -1`, so they stay conservative there);
:func:`simulate_force_position` measures the behaviour for any setting.

Examples
--------
>>> g = suggest_gains(mass=1/300, damping=1/30, dt=1e-3, A_f=1e7, A_d=1e5)
>>> check_gains(**g, mass=1/300, damping=1/30, dt=1e-3, A_f=1e7, A_d=1e5).ok
True
"""
from __future__ import annotations

from dataclasses import dataclass

import math

import numpy as np

from arsurf.errors import HapticsError
from arsurf.haptics.device import _vec3

__all__ = ["Bound", "GainCheck", "check_gains", "coupling_stiffness", "suggest_gains"]

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
    required : bool
        Whether :attr:`GainCheck.ok` needs it (a bound reported for comparison is not required).
    """

    name: str
    relation: str
    value: np.ndarray
    limit: np.ndarray
    ok: np.ndarray
    source: str
    required: bool = True


@dataclass(frozen=True)
class GainCheck:
    """Result of :func:`check_gains`: whether a gain set is admissible and which bound fails."""

    bounds: tuple[Bound, ...]

    @property
    def ok(self) -> bool:
        """All required bounds hold on every axis."""
        return all(bool(b.ok.all()) for b in self.bounds if b.required)

    @property
    def table_ok(self) -> bool:
        """The three bounds of (corrected) Table II hold on every axis."""
        return all(bool(b.ok.all()) for b in self.bounds if b.name in ("K_fp_max", "B_fp_min", "G_n_max"))

    @property
    def failed(self) -> list[str]:
        """Failed bounds as ``"name (axis)"``, e.g. ``["G_n_max (x)"]``."""
        return [f"{b.name} ({_AXES[i]})" for b in self.bounds for i in range(3) if b.required and not b.ok[i]]

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
                if b.required and not b.ok[i]:
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


def check_gains(K_fp, B_fp, G_n, *, A_f, A_d, mass, damping, dt, env_stiffness=0.0,
                slave_bound: str = "applied") -> GainCheck:
    r"""Check force-position gains against the admissible ranges (corrected Table II + joint).

    The slave-gain bound is reported twice. Table II as printed (docs/design.rst, "Known errors in the sources") reads
    :math:`G_n \le A_f / (A_d (K_{fp} T_e/2 + B_{fp}))` (``G_n_max``); the gains the authors used
    (825 and 19.8, [Bolopion] Figs. 5-6) are :math:`0.99\,A_f / (A_d (K_{fp} T_e + B_{fp}))`: they
    applied the bound with :math:`T_e`, up to 1.7x tighter (``G_n_max_applied``). By default
    (``slave_bound="applied"``) the conservative one is required; ``"printed"`` requires only
    Table II's as printed (the other is then reported, not required).

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
    slave_bound : {"applied", "printed"}
        Which slave-gain bound is required (both are reported).

    Returns
    -------
    GainCheck
        ``ok``, ``table_ok``, ``failed`` and the six :class:`Bound` records.

    Examples
    --------
    >>> c = check_gains(100.0, 0.1, 825.0, A_f=25e6, A_d=50e3, mass=0.5, damping=0.2, dt=5e-3)
    >>> c.ok, round(float(c.bound("G_n_max").limit[0]), 2)      # [Bolopion], Fig. 5 (x axis)
    (True, 1428.57)
    >>> round(825.0 / float(c.bound("G_n_max_applied").limit[0]), 4)  # the authors' 0.99 of the T_e bound
    0.99
    >>> check_gains(100.0, 0.1, 1000.0, A_f=25e6, A_d=50e3, mass=0.5, damping=0.2, dt=5e-3).failed[:1]
    ['G_n_max_applied (x)']
    >>> check_gains(100.0, 0.1, 2000.0, A_f=25e6, A_d=50e3, mass=0.5, damping=0.2, dt=5e-3).failed[:1]
    ['G_n_max (x)']
    """
    if slave_bound not in ("applied", "printed"):
        raise HapticsError(f"slave_bound must be 'applied' or 'printed' (got {slave_bound!r})")
    K, B, G, Af, Ad, M, Bv, T, ke = _gain_arrays(K_fp, B_fp, G_n, A_f, A_d, mass, damping, dt, env_stiffness)
    table = "[Bolopion] Table II as corrected in docs/design.rst"
    applied = "[Bolopion] as applied by its authors (T_e, not T_e/2: G_n = 825 and 19.8 are 0.99 of it)"
    g_applied = Af / (Ad * (K * T + B))
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
        Bound("G_n_max_applied", "<=", G, g_applied, G <= g_applied, applied, required=slave_bound == "applied"),
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
    times the largest value the joint condition and the conservative slave bound allow.

    Examples
    --------
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
    g_applied = Af / (Ad * (K * T + B))  # the conservative slave bound (check_gains' default)
    G = slave_margin * np.minimum(g_joint, g_applied)
    return {"K_fp": K, "B_fp": B, "G_n": G}


def coupling_stiffness(info, rate: float) -> float:
    r"""Stiffness (N/m at the handle) of the direct coupling's virtual coupling for a device and rate.

    The largest stiffness a zero-order-hold loop of period :math:`T` renders passively on a
    device with physical damping :math:`b` is :math:`K < 2b/T` (Colgate & Schenkel 1997, the
    virtual wall with no virtual damping), and never more than the device's own stable maximum:

    .. math:: k_{vc} = \min\left(\min_i K_{max,i},\; \frac{2\,\min_i b_i}{T}\right).

    Without a known damping (``info.damping`` None: most vendors do not publish it) half the
    vendor's maximum stiffness is taken; the passivity controller
    (:mod:`arsurf.haptics.passivity`) guards the rest either way.

    Examples
    --------
    >>> from arsurf.haptics.virtual_device import VirtualDevice
    >>> round(coupling_stiffness(VirtualDevice(dt=1e-3).info, 1000.0), 2)   # 2 x (1/30 N s/m) / 1 ms
    66.67
    """
    rate = float(rate)
    if not (math.isfinite(rate) and rate > 0.0):
        raise HapticsError(f"rate must be a positive loop rate in Hz (got {rate!r})")
    k_max = float(np.min(info.max_stiffness))
    if info.damping is None:
        return 0.5 * k_max
    return min(k_max, 2.0 * float(np.min(info.damping)) * rate)
