r"""Closed-loop simulation of the force-position coupling: virtual master, slave, environment.

Measures what the bounds of :mod:`arsurf.haptics.gains` predict: an admissible gain set settles,
one outside them oscillates (:func:`envelope_decay_ratio` > 1).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from arsurf.errors import HapticsError
from arsurf.haptics.coupling import ForcePositionCoupling
from arsurf.haptics.device import _vec3
from arsurf.haptics.virtual_device import HandModel, VirtualDevice

__all__ = ["CouplingSimulation", "envelope_decay_ratio", "simulate_force_position"]

_DIVERGED = 1e6  # m or N: far outside anything physical, the simulation stops


def envelope_decay_ratio(signal, window: float = 0.2) -> float:
    """How the oscillation envelope of ``signal`` evolves: late envelope / early envelope.

    The envelope is the largest tick-to-tick change :math:`|s_k - s_{k-1}|` in a window (a
    constant offset does not count; a steady drift gives 1); the ratio compares the last ``window``
    fraction of the record with the first. Below 1: the motion dies out (stable rendering); about 1:
    sustained oscillation; above 1: growth. ``inf`` if the record is not finite.

    Examples
    --------
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

    Examples
    --------
    >>> from arsurf.haptics.gains import suggest_gains
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
