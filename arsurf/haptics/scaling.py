"""Scaling between the hand's world and the probe's: positions down, forces up, with a clutch.

**Position** (master -> probe), per axis, with the clutch anchors :math:`x_0` (master) and
:math:`p_0` (probe):

.. math:: p = p_0 + s \\odot (x - x_0), \\qquad s = 1/A_d ,

clamped to the probe's range (the piezo travel). [Alabdulmuhsin] (section 4.2.1) states the scale as a
*sensitivity* in probe nm per haptic mm, :math:`S = 10^{6} s`; the smallest probe step the hand
can make is the *resolution* :math:`S \\times` 1 mm (the human hand's own resolution there, not
the device's 0.023 mm) and the probe *range* covered by the haptic workspace is
:math:`S \\times` workspace: Tables 4.2 and 4.3 (e.g. 5000 nm / 120 mm: 41.7 nm, 5000 nm).

**Clutch / indexing** ([Bolopion] section V-A, [Alabdulmuhsin] section 3.2): while the clutch button is
held the probe stays where it is and the master moves freely; on release the anchors become
:math:`x_0 \\leftarrow x`, :math:`p_0 \\leftarrow p`, so the probe continues from where it stopped
and the operator has re-centred the stylus in its workspace.

**Force** (probe -> master): :math:`F_h = K_f \\odot F_{probe}` ([Alabdulmuhsin] Eq. 9-10, :math:`K_f`
= 15e6; [Bolopion] uses per-axis :math:`A_f` = 25e6 along x and 2e6 along y).

Kernels take plain float64 arrays and return bit flags (:data:`CLUTCHED`, :data:`CLAMPED`,
:data:`MASTER_OUTSIDE`, :data:`NONFINITE`).

Examples
--------
>>> s = PositionScaling.from_sensitivity(5000 / 120)          # nm per mm, [Alabdulmuhsin] Table 4.2
>>> (s.map([0.012, 0.0, 0.0]) * 1e9).round(3).tolist()        # 12 mm of stylus -> 500 nm of probe
[500.0, 0.0, 0.0]
>>> ForceScaling(15e6).apply([0.0, 0.0, 100e-9]).round(3).tolist()   # 100 nN -> 1.5 N
[0.0, 0.0, 1.5]
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from arsurf import status
from arsurf._layout import Layout
from arsurf.errors import HapticsError
from arsurf.haptics.device import BUTTON_1, _vec3

__all__ = [
    "CLAMPED",
    "CLUTCHED",
    "HAND_RESOLUTION",
    "MASTER_OUTSIDE",
    "NONFINITE",
    "POSITION_PARAMS",
    "POSITION_STATE",
    "SEED001_K_F",
    "ForceScaling",
    "PositionScaling",
    "force_scale_step",
    "position_map_step",
]

#: The human hand positions a stylus to about 1 mm ([Alabdulmuhsin] section 4.2.1); the resolution column
#: of Tables 4.2-4.3 is the sensitivity times this.
HAND_RESOLUTION = 1e-3  # m
#: Force scale of [Alabdulmuhsin] (section 4.2.2): 15e6 (N on the hand per N on the probe).
SEED001_K_F = 15e6

# flags returned by the kernels (one table for all loop stages: arsurf.status)
CLUTCHED = status.CLUTCHED  #: clutch held: probe frozen
CLAMPED = status.CLAMPED  #: probe clamped to its range
MASTER_OUTSIDE = status.MASTER_OUTSIDE  #: master outside its workspace box (re-centre with the clutch)
NONFINITE = status.NONFINITE  #: non-finite input, previous output kept

#: the parameters of :func:`position_map_step` (``PositionScaling.params``): scale (probe m per
#: master m), the probe range (m), the master workspace half-extent (m)
POSITION_PARAMS = Layout("position-map parameters", [
    ("scale", 3), ("probe_lower", 3), ("probe_upper", 3), ("workspace_half_extent", 3)])
#: its state (``PositionScaling.state``): the master and probe anchors (m), the last probe (m),
#: the clutch held (0 or 1)
POSITION_STATE = Layout("position-map state", [
    ("master_anchor", 3), ("probe_anchor", 3), ("last_probe", 3), ("clutched", 1)])
# the offsets as the kernel uses them
_P_SCALE, _P_LO = POSITION_PARAMS.offset("scale"), POSITION_PARAMS.offset("probe_lower")
_P_HI, _P_WS = POSITION_PARAMS.offset("probe_upper"), POSITION_PARAMS.offset("workspace_half_extent")
_S_X0, _S_P0 = POSITION_STATE.offset("master_anchor"), POSITION_STATE.offset("probe_anchor")
_S_LAST, _S_CLUTCH = POSITION_STATE.offset("last_probe"), POSITION_STATE.offset("clutched")


@njit(cache=True)
def position_map_step(params, state, x, buttons, clutch_mask, out):
    """Map a master position ``x`` (3,) to the probe position ``out`` (3,) with clutch and limits.

    ``params`` (:data:`POSITION_PARAMS`), ``state`` (:data:`POSITION_STATE`, updated). Returns bit
    flags.
    """
    flags = 0
    for i in range(3):
        if not math.isfinite(x[i]):
            for j in range(3):
                out[j] = state[_S_LAST + j]
            return NONFINITE
    for i in range(3):
        if abs(x[i]) > params[_P_WS + i]:
            flags |= MASTER_OUTSIDE
    if (buttons & clutch_mask) != 0:
        state[_S_CLUTCH] = 1.0
        for j in range(3):
            out[j] = state[_S_LAST + j]
        return flags | CLUTCHED
    if state[_S_CLUTCH] != 0.0:  # released: re-anchor where the master and the probe are now
        state[_S_CLUTCH] = 0.0
        for j in range(3):
            state[_S_X0 + j] = x[j]
            state[_S_P0 + j] = state[_S_LAST + j]
    for j in range(3):
        p = state[_S_P0 + j] + params[_P_SCALE + j] * (x[j] - state[_S_X0 + j])
        if p < params[_P_LO + j]:
            p = params[_P_LO + j]
            flags |= CLAMPED
        elif p > params[_P_HI + j]:
            p = params[_P_HI + j]
            flags |= CLAMPED
        state[_S_LAST + j] = p
        out[j] = p
    return flags


@njit(cache=True)
def force_scale_step(gain, f, out):
    """``out = gain * f`` per axis; returns :data:`NONFINITE` if ``f`` is not finite (written anyway)."""
    flags = 0
    for j in range(3):
        out[j] = gain[j] * f[j]
        if not math.isfinite(f[j]):
            flags = NONFINITE
    return flags


class PositionScaling:
    """Master -> probe position map: per-axis scale, clutch re-centring, probe and workspace limits.

    Parameters
    ----------
    scale : float or (3,)
        Probe metres per master metre, :math:`s = 1/A_d` (e.g. 5000 nm / 120 mm = 4.17e-5).
        Non-zero; a negative value flips an axis.
    probe_origin : (3,) float, m
        Probe position when the master is at ``master_origin``.
    master_origin : (3,) float, m
        Master position that maps to ``probe_origin`` (default: the device's home, 0).
    probe_limits : None or (lower (3,), upper (3,)), m
        Probe range (the piezo travel); the probe is clamped to it.
    workspace : None or (3,) float, m
        Master workspace extents (centred on 0); outside it the map flags :data:`MASTER_OUTSIDE`.
    clutch_mask : int
        Button bits that hold the clutch (default :data:`~arsurf.haptics.device.BUTTON_1`; 0: no clutch).

    Attributes
    ----------
    params, state : float64 arrays
        Kernel arguments of :func:`position_map_step` (for a compiled tick).
    flags : int
        Flags of the last :meth:`map`.

    Examples
    --------
    >>> s = PositionScaling(1e-5)                      # 1 mm of stylus -> 10 nm of probe
    >>> p = s.map([0.01, 0, 0])                        # 100 nm
    >>> p = s.map([0.03, 0, 0], buttons=1)             # clutch held: the probe stays
    >>> p = s.map([0.03, 0, 0]); p = s.map([0.04, 0, 0])   # released, then 10 mm more
    >>> (p * 1e9).round(6).tolist()
    [200.0, 0.0, 0.0]
    """

    def __init__(self, scale, probe_origin=(0.0, 0.0, 0.0), master_origin=(0.0, 0.0, 0.0),
                 probe_limits=None, workspace=None, clutch_mask: int = BUTTON_1) -> None:
        sc = _vec3(scale, "scale")
        if (sc == 0).any():
            raise HapticsError(
                f"scale must be non-zero on every axis (got {sc.tolist()}); it is probe metres per master metre"
            )
        self.params = POSITION_PARAMS.zeros()
        self.params[_P_SCALE:_P_SCALE + 3] = sc
        if probe_limits is None:
            lo = np.full(3, -np.inf)
            hi = np.full(3, np.inf)
        else:
            try:
                lo_, hi_ = probe_limits
            except (TypeError, ValueError) as exc:
                raise HapticsError("probe_limits must be None or a pair (lower (3,), upper (3,)) in metres") from exc
            lo = _vec3(lo_, "probe_limits lower")
            hi = _vec3(hi_, "probe_limits upper")
            if not (lo < hi).all():
                raise HapticsError(f"probe_limits lower must be below upper on every axis (got {lo.tolist()}, {hi.tolist()})")
        self.params[_P_LO:_P_LO + 3] = lo
        self.params[_P_HI:_P_HI + 3] = hi
        if workspace is None:
            self.params[_P_WS:_P_WS + 3] = np.inf
        else:
            ws = _vec3(workspace, "workspace")
            if (ws <= 0).any():
                raise HapticsError(f"workspace extents must be positive (got {ws.tolist()} m)")
            self.params[_P_WS:_P_WS + 3] = 0.5 * ws
        if not isinstance(clutch_mask, (int, np.integer)) or clutch_mask < 0:
            raise HapticsError(f"clutch_mask must be a non-negative button bitmask (got {clutch_mask!r})")
        self.clutch_mask = int(clutch_mask)
        self.state = POSITION_STATE.zeros()
        self._out = np.zeros(3)
        self.flags = 0
        self.recentre(master_origin, probe_origin)

    # -- construction from the seed's quantities ------------------------------------------------
    @classmethod
    def from_sensitivity(cls, nm_per_mm, **kwargs) -> "PositionScaling":
        """From a sensitivity in probe nm per haptic mm ([Alabdulmuhsin] Tables 4.2-4.3): :math:`s = 10^{-6} S`.

        Examples
        --------
        >>> PositionScaling.from_sensitivity(1000 / 120).scale.round(9).tolist()
        [8.333e-06, 8.333e-06, 8.333e-06]
        """
        s = _vec3(nm_per_mm, "sensitivity (nm/mm)")
        return cls(s * 1e-9 / 1e-3, **kwargs)

    @classmethod
    def from_ranges(cls, probe_range, master_range, **kwargs) -> "PositionScaling":
        """Map a master range (m) onto a probe range (m) per axis: :math:`s = R_{probe} / R_{master}`.

        Examples
        --------
        >>> PositionScaling.from_ranges(5e-6, (0.12, 0.16, 0.12)).sensitivity_nm_per_mm.round(2).tolist()
        [41.67, 31.25, 41.67]
        """
        pr = _vec3(probe_range, "probe_range")
        mr = _vec3(master_range, "master_range")
        if (pr <= 0).any() or (mr <= 0).any():
            raise HapticsError(f"ranges must be positive (got probe {pr.tolist()} m, master {mr.tolist()} m)")
        return cls(pr / mr, **kwargs)

    # -- derived quantities ([Alabdulmuhsin] Tables 4.2 and 4.3) ------------------------------------
    @property
    def scale(self) -> np.ndarray:
        """Probe metres per master metre, (3,)."""
        return self.params[_P_SCALE:_P_SCALE + 3].copy()

    @property
    def A_d(self) -> np.ndarray:
        """Position down-scaling factor :math:`A_d = 1/s` ([Bolopion]), (3,)."""
        return 1.0 / self.params[_P_SCALE:_P_SCALE + 3]

    @property
    def sensitivity_nm_per_mm(self) -> np.ndarray:
        """Probe nm per haptic mm, (3,) ([Alabdulmuhsin]'s 'sensitivity')."""
        return self.params[_P_SCALE:_P_SCALE + 3] * 1e6

    def resolution(self, master_resolution: float = HAND_RESOLUTION) -> np.ndarray:
        """Smallest probe step (m) for a master step of ``master_resolution`` (default: the hand's 1 mm)."""
        return np.abs(self.params[_P_SCALE:_P_SCALE + 3]) * float(master_resolution)

    def probe_range(self, master_range) -> np.ndarray:
        """Probe travel (m) covered by a master travel ``master_range`` (m), (3,)."""
        return np.abs(self.params[_P_SCALE:_P_SCALE + 3]) * _vec3(master_range, "master_range")

    # -- the map ---------------------------------------------------------------------------------
    def recentre(self, master_position, probe_position=None) -> None:
        """Anchor the map: ``master_position`` now maps to ``probe_position`` (default: current probe)."""
        x0 = _vec3(master_position, "master_position")
        p0 = self.state[_S_LAST:_S_LAST + 3].copy() if probe_position is None else _vec3(probe_position, "probe_position")
        self.state[_S_X0:_S_X0 + 3] = x0
        self.state[_S_P0:_S_P0 + 3] = p0
        self.state[_S_LAST:_S_LAST + 3] = np.clip(p0, self.params[_P_LO:_P_LO + 3], self.params[_P_HI:_P_HI + 3])
        self.state[_S_CLUTCH] = 0.0

    def map(self, master_position, buttons: int = 0, out: np.ndarray | None = None) -> np.ndarray:
        """Probe position (3,) m for the master position (3,) m; sets :attr:`flags`."""
        x = master_position if isinstance(master_position, np.ndarray) and master_position.dtype == np.float64 \
            else np.asarray(master_position, dtype=np.float64)
        o = self._out if out is None else out
        self.flags = position_map_step(self.params, self.state, x, int(buttons), self.clutch_mask, o)
        return o.copy() if out is None else o

    def to_master(self, probe_position) -> np.ndarray:
        """Master position (3,) that maps to ``probe_position`` with the current anchors (no limits)."""
        p = _vec3(probe_position, "probe_position")
        return self.state[_S_X0:_S_X0 + 3] + (p - self.state[_S_P0:_S_P0 + 3]) / self.params[_P_SCALE:_P_SCALE + 3]


class ForceScaling:
    """Probe force -> hand force, per axis: :math:`F_h = K_f \\odot F_{probe}` ([Alabdulmuhsin] Eq. 9-10).

    Parameters
    ----------
    gain : float or (3,)
        :math:`K_f` ([Alabdulmuhsin]: 15e6) or per-axis :math:`A_f` ([Bolopion]: 25e6 along x, 2e6 along y).
        Positive and finite.

    Examples
    --------
    >>> ForceScaling((25e6, 2e6, 25e6)).apply([1.7e-6, 1e-7, 0.0]).round(6).tolist()
    [42.5, 0.2, 0.0]
    """

    def __init__(self, gain) -> None:
        g = _vec3(gain, "force gain")
        if (g <= 0).any():
            raise HapticsError(f"force gain must be positive on every axis (got {g.tolist()}); it is N on the hand per N on the probe")
        self.gain = g
        self._out = np.zeros(3)
        self.flags = 0

    def apply(self, force, out: np.ndarray | None = None) -> np.ndarray:
        """Hand force (3,) N for the probe force ``force`` (3,) N; NaN passes through, flagged."""
        f = force if isinstance(force, np.ndarray) and force.dtype == np.float64 else np.asarray(force, dtype=np.float64)
        if f.shape != (3,):
            raise HapticsError(f"force must have shape (3,) (got {f.shape})")
        o = self._out if out is None else out
        self.flags = force_scale_step(self.gain, f, o)
        return o.copy() if out is None else o

    def inverse(self, hand_force) -> np.ndarray:
        """Probe force (3,) N that renders ``hand_force`` (3,) N."""
        return _vec3(hand_force, "hand_force") / self.gain
