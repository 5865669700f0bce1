"""Four-quadrant photodiode: quadrant voltages -> vertical/lateral signals -> cantilever angles.

Quadrant layout ([Alabdulmuhsin] Fig. 2.2 and [Bolopion] Fig. 1 describe the same cell)::

        A (top-left)    | B (top-right)
        ----------------+----------------
        C (bottom-left) | D (bottom-right)

[Bolopion] names them T_l, T_r, B_l, B_r = A, B, C, D. Two conventions for the signals:

* ``"normalized"`` ([Alabdulmuhsin] Eq. 3, 5): divided by the total light, dimensionless, in [-1, 1],
  insensitive to laser power:

  .. math:: V_v = \\frac{(A+B)-(C+D)}{A+B+C+D}, \\qquad V_h = \\frac{(A+C)-(B+D)}{A+B+C+D}

* ``"difference"`` ([Bolopion] Eq. 1): raw differences in volts,
  :math:`u_v = (A+B)-(C+D)`, :math:`u_h = (A+C)-(B+D)`.

A vertical spot displacement comes from bending, a horizontal one from torsion. Sensitivities
turn signals into angles: ``bending = vertical_sensitivity * V_v``, ``torsion =
lateral_sensitivity * V_h`` (rad per signal unit; either may be negative, depending on how the
detector is mounted - [Alabdulmuhsin] finds a negative normal gain).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from arsurf.errors import ForceError

__all__ = ["CONVENTIONS", "Photodiode", "quadrant_signals", "quadrants_from_signals"]

CONVENTIONS = ("normalized", "difference")


def _check_convention(convention: str) -> None:
    if convention not in CONVENTIONS:
        raise ForceError(
            f"convention must be 'normalized' ([Alabdulmuhsin], divided by the sum) or 'difference' "
            f"([Bolopion], raw differences) (got {convention!r})"
        )


def quadrant_signals(a, b, c, d, convention: str = "normalized"):
    """Vertical and lateral signals from the four quadrant voltages.

    Parameters
    ----------
    a, b, c, d : float or array (broadcastable), volts
        Top-left, top-right, bottom-left, bottom-right quadrant outputs.
    convention : {"normalized", "difference"}
        Divide by the total A+B+C+D ([Alabdulmuhsin]) or not ([Bolopion]).

    Returns
    -------
    vertical, lateral : float or array
        Dimensionless (normalized) or volts (difference).

    Raises
    ------
    ForceError
        NaN voltages, or a non-positive total in the normalized convention (no light on the cell).

    Examples
    --------
    >>> quadrant_signals(3.0, 3.0, 1.0, 1.0)
    (0.5, 0.0)
    >>> quadrant_signals(3.0, 3.0, 1.0, 1.0, convention="difference")
    (4.0, 0.0)
    """
    _check_convention(convention)
    arrays = np.broadcast_arrays(*(np.asarray(x, dtype=np.float64) for x in (a, b, c, d)))
    qa, qb, qc, qd = arrays
    if not all(np.all(np.isfinite(q)) for q in arrays):
        raise ForceError("quadrant voltages contain NaN or infinite values; drop or interpolate those samples")
    vertical = (qa + qb) - (qc + qd)
    lateral = (qa + qc) - (qb + qd)
    if convention == "normalized":
        total = qa + qb + qc + qd
        if np.any(total <= 0.0):
            raise ForceError(
                f"the total light A+B+C+D must be positive to normalise (smallest got {float(np.min(total))!r} V); "
                "check the laser alignment or use convention='difference'"
            )
        vertical = vertical / total
        lateral = lateral / total
    if vertical.ndim == 0:
        return float(vertical), float(lateral)
    return vertical, lateral


def quadrants_from_signals(vertical, lateral, total: float = 4.0, convention: str = "normalized"):
    """Quadrant voltages of a uniform spot giving the requested signals (inverse of :func:`quadrant_signals`).

    A small round spot moved by (vertical, lateral) shares its light as

    .. math:: A, B, C, D = \\tfrac{S}{4}(1 + V \\pm H),\\; \\tfrac{S}{4}(1 - V \\pm H)

    with S = ``total``; for the difference convention V and H are first divided by S. The
    diagonal combination (A+D)-(B+C) is zero.

    Parameters
    ----------
    vertical, lateral : float or array
    total : float, volts
        Total light A+B+C+D (> 0).

    Returns
    -------
    a, b, c, d : float or array, volts
    """
    _check_convention(convention)
    if not (math.isfinite(total) and total > 0.0):
        raise ForceError(f"total must be a positive voltage (got {total!r})")
    v = np.asarray(vertical, dtype=np.float64)
    h = np.asarray(lateral, dtype=np.float64)
    if convention == "difference":
        v = v / total
        h = h / total
    q = total / 4.0
    out = (q * (1 + v + h), q * (1 + v - h), q * (1 - v + h), q * (1 - v - h))
    if np.ndim(out[0]) == 0:
        return tuple(float(x) for x in out)
    return out


@dataclass(frozen=True)
class Photodiode:
    """Signal -> angle conversion of an optical-lever detector.

    .. math:: \\Delta\\alpha = S_v V_v, \\qquad \\Delta\\theta = S_h V_h

    Parameters
    ----------
    vertical_sensitivity : float, rad per signal unit
        Bending angle per unit vertical signal (non-zero; sign follows the detector mounting).
    lateral_sensitivity : float, rad per signal unit
        Torsion angle per unit lateral signal (non-zero). [MWCNT] takes it equal to the vertical
        one (k_h = k_v / l_c), since the cell has one angular sensitivity in both directions.
    convention : {"normalized", "difference"}
        Which signals the sensitivities refer to (see :func:`quadrant_signals`).

    Examples
    --------
    >>> pd = Photodiode(0.01, 0.01)
    >>> pd.angles(0.2, -0.1)
    (0.002, -0.001)
    """

    vertical_sensitivity: float
    lateral_sensitivity: float
    convention: str = "normalized"

    def __post_init__(self) -> None:
        _check_convention(self.convention)
        for name in ("vertical_sensitivity", "lateral_sensitivity"):
            value = getattr(self, name)
            try:
                v = float(value)
            except (TypeError, ValueError):
                raise ForceError(f"{name} must be a number (got {value!r})") from None
            if not (math.isfinite(v) and v != 0.0):
                raise ForceError(
                    f"{name} must be finite and non-zero (got {value!r} rad per signal unit); calibrate it "
                    "(arsurf.force.calibration) or derive it with Photodiode.from_deflection_sensitivity"
                )
            object.__setattr__(self, name, v)

    @classmethod
    def from_deflection_sensitivity(
        cls, deflection_sensitivity: float, length: float, lateral_sensitivity: float | None = None,
        convention: str = "normalized",
    ) -> "Photodiode":
        """Build from a calibrated deflection sensitivity (m of end deflection per signal unit).

        An end-loaded beam (tip pressed on a hard sample during calibration) has end slope
        3 delta / (2 l), so the angular sensitivity is

        .. math:: S_v = \\frac{3}{2l}\\,S_{\\delta}

        The lateral sensitivity defaults to the same angular sensitivity ([MWCNT], sec. 2.3.2).

        Parameters
        ----------
        deflection_sensitivity : float, metres per signal unit (non-zero)
        length : float, metres (> 0), cantilever length
        lateral_sensitivity : float, optional, rad per signal unit
        """
        for name, value in (("deflection_sensitivity", deflection_sensitivity), ("length", length)):
            if not (isinstance(value, (int, float, np.floating)) and math.isfinite(value) and value != 0.0):
                raise ForceError(f"{name} must be finite and non-zero (got {value!r})")
        if length <= 0.0:
            raise ForceError(f"length must be positive (got {length!r} m)")
        s_v = 1.5 * float(deflection_sensitivity) / float(length)
        return cls(s_v, s_v if lateral_sensitivity is None else lateral_sensitivity, convention)

    def angles(self, vertical, lateral):
        """Bending and torsion (rad) from vertical and lateral signals (float or arrays)."""
        v = np.asarray(vertical, dtype=np.float64)
        h = np.asarray(lateral, dtype=np.float64)
        if not (np.all(np.isfinite(v)) and np.all(np.isfinite(h))):
            raise ForceError("photodiode signals contain NaN or infinite values; drop or interpolate those samples")
        b = self.vertical_sensitivity * v
        t = self.lateral_sensitivity * h
        if b.ndim == 0 and t.ndim == 0:
            return float(b), float(t)
        return b, t

    def signals(self, bending, torsion):
        """Vertical and lateral signals produced by given bending and torsion angles (rad)."""
        b = np.asarray(bending, dtype=np.float64)
        t = np.asarray(torsion, dtype=np.float64)
        if not (np.all(np.isfinite(b)) and np.all(np.isfinite(t))):
            raise ForceError("angles contain NaN or infinite values")
        v = b / self.vertical_sensitivity
        h = t / self.lateral_sensitivity
        if v.ndim == 0 and h.ndim == 0:
            return float(v), float(h)
        return v, h

    def angles_from_quadrants(self, a, b, c, d):
        """Bending and torsion straight from the quadrant voltages (this detector's convention)."""
        v, h = quadrant_signals(a, b, c, d, self.convention)
        return self.angles(v, h)
