"""Photodiode signal -> haptic force gains ([Alabdulmuhsin], sec. 4.2.2, Tables 4.4-4.6).

The thesis scales the cantilever forces by one gain K_f into the haptic device
(F_h,z = K_f F_n, F_h,y = K_f F_l, Eq. 9-10), with F_n = k S_n V_v and F_l = G_l V_h (Eq. 7, 25).
The resulting force sensitivities are:

.. math::

    \\frac{F_{h,z}}{V_v} = K_f k S_n,\\qquad \\frac{F_{h,y}}{V_h} = K_f G_l
    \\qquad (\\text{Table 4.4}),

    \\frac{F_{h,z}}{\\delta_z} = K_f k \\;(\\text{Eq. 26, Table 4.5}),\\qquad
    \\frac{F_{h,y}}{\\delta_y} = \\frac{K_f G_l\\, l}{h S_n} \\;(\\text{Eq. 28, Table 4.6}),

where delta_y is the lateral displacement of the tip apex (twist theta_x = delta_y / h) and the
lateral angular sensitivity is taken as S_n / l ([Alabdulmuhsin] after Eq. 27). The tables list
magnitudes; the values returned here keep the signs of S_n and G_l.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from arsurf.errors import ForceError

__all__ = ["HapticForceGain", "signal_to_haptic_force_gain"]


@dataclass(frozen=True)
class HapticForceGain:
    """Haptic force per unit signal / displacement.

    Attributes
    ----------
    normal_per_signal : float, N per vertical signal unit (Table 4.4, F_h,z / V_v)
    lateral_per_signal : float, N per lateral signal unit (Table 4.4, F_h,y / V_h)
    normal_per_deflection : float, N/m (Table 4.5, F_h,z / delta_z)
    lateral_per_displacement : float or None, N/m (Table 4.6, F_h,y / delta_y); None without geometry
    """

    normal_per_signal: float
    lateral_per_signal: float
    normal_per_deflection: float
    lateral_per_displacement: float | None


def signal_to_haptic_force_gain(
    force_scale: float, spring_constant: float, normal_sensitivity: float, lateral_gain: float,
    length: float | None = None, tip_height: float | None = None,
) -> HapticForceGain:
    """Gains from photodiode signals (and tip displacements) to the force on the haptic device.

    Parameters
    ----------
    force_scale : float
        K_f, haptic newtons per cantilever newton (> 0; [Alabdulmuhsin] uses 15e6).
    spring_constant : float, N/m (k > 0)
    normal_sensitivity : float, metres per vertical signal unit (S_n, non-zero)
    lateral_gain : float, N per lateral signal unit (G_l, non-zero)
    length, tip_height : float, metres, optional
        Cantilever length l and tip height h, for :attr:`HapticForceGain.lateral_per_displacement`.

    Examples
    --------
    >>> g = signal_to_haptic_force_gain(15e6, 0.3, 1117e-9, -63.78e-9, 450e-6, 15e-6)
    >>> round(g.normal_per_signal, 4), round(g.lateral_per_signal, 4)
    (5.0265, -0.9567)
    """
    for name, value in (("force_scale", force_scale), ("spring_constant", spring_constant)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
            raise ForceError(f"{name} must be positive and finite (got {value!r})")
    for name, value in (("normal_sensitivity", normal_sensitivity), ("lateral_gain", lateral_gain)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value != 0.0):
            raise ForceError(f"{name} must be finite and non-zero (got {value!r})")
    lateral_disp = None
    if (length is None) != (tip_height is None):
        raise ForceError("give both length and tip_height (or neither) for the displacement gain")
    if length is not None:
        for name, value in (("length", length), ("tip_height", tip_height)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
                raise ForceError(f"{name} must be positive (got {value!r} m)")
        lateral_disp = force_scale * lateral_gain * length / (tip_height * normal_sensitivity)
    return HapticForceGain(
        force_scale * spring_constant * normal_sensitivity,
        force_scale * lateral_gain,
        force_scale * spring_constant,
        lateral_disp,
    )
