r"""A scripted press, slide and retract of the tip through the surface model (no hand, no device).

The tip centre is driven in three straight legs of ``steps`` ticks each through an
:class:`~arsurf.model.ARModel` on its surface, starting above the point ``(x, y)``:

1. **press**: from 2 nm above contact (the rest surface plus the tip radius) down to the
   indentation ``depth``;
2. **slide**: ``slide`` metres along +x at that centre height (the depth follows the topography);
3. **retract**: straight up to 10 nm above the start of contact.

:func:`press_slide_retract` answers the largest depth and load, the contact radius at the largest
load (Maugis-Dugdale, :mod:`arsurf.contact.maugis_dugdale`), the pull-off force (the most tensile
load while retracting) and the friction during the slide: the mean tangential force
:math:`|F - P n|` over the ticks in contact and the mean ratio :math:`|F_t| / N` over the ticks
where the friction proxy slipped, :math:`N` the friction's normal of the model's law
(:mod:`arsurf.contact.friction`: :math:`P + |P_c|` for the adhesive law, :math:`P` for the
compressive one; on a flat surface of one material it equals the kinetic coefficient). The motion
is scripted, so the answers depend only on the contact physics; :mod:`arsurf.feel_scenarios`
scores the feel through the whole haptic loop. This is the physics of ``arsurf batch sweep``
(:mod:`arsurf.batch.pipelines`), one grid point per call. Lengths in m, forces in N.
"""
from __future__ import annotations

import math

import numpy as np

from arsurf.model import M_DEPTH, M_IN_CONTACT, M_LOAD, M_NX, M_RADIUS, M_SIM_FX, M_SLIPPING

__all__ = ["press_slide_retract"]

#: the press starts this far above contact, the retract ends this far above it (m)
APPROACH = 2e-9
LIFT = 10e-9


def press_slide_retract(model, x: float, y: float, *, tip_radius: float, depth: float, slide: float,
                        steps: int) -> dict:
    """Drive ``model`` (an ARModel on its surface) through press, slide and retract at ``(x, y)`` (m).

    Parameters
    ----------
    model : arsurf.model.ARModel
        Stepped ``3 * steps`` times, then reset.
    x, y : float, m
        Where the press starts (inside the surface's domain).
    tip_radius : float, m
        The tip radius of the model (the centre height of first contact is the surface plus it).
    depth, slide : float, m
        Indentation of the press, length of the slide along +x.
    steps : int
        Ticks of each leg.

    Returns
    -------
    dict
        ``max_depth_m``, ``peak_load_N``, ``contact_radius_m``, ``pull_off_force_N``,
        ``mean_friction_force_N``, ``friction_ratio`` (nan when nothing slipped), ``slip_fraction``.
    """
    z_touch = float(model.surface.evaluate(x, y)[2]) + tip_radius  # centre height of first contact (no adhesion)
    n = steps
    ramp = np.linspace(0.0, 1.0, n)
    legs = [np.column_stack([np.full(n, x), np.full(n, y), z_touch + APPROACH - (APPROACH + depth) * ramp]),
            np.column_stack([x + slide * ramp, np.full(n, y), np.full(n, z_touch - depth)]),
            np.column_stack([np.full(n, x + slide), np.full(n, y), z_touch - depth + (depth + LIFT) * ramp])]
    rows = []
    for leg in legs:
        out = np.empty((n, model.out.size))
        for k in range(n):
            model.step(leg[k])
            out[k] = model.out
        rows.append(out)
    press_slide = np.vstack(rows[:2])
    k_peak = int(np.argmax(press_slide[:, M_LOAD]))
    slid, retract = rows[1], rows[2]
    normal = slid[:, M_NX:M_NX + 3]
    tangential = np.linalg.norm(slid[:, M_SIM_FX:M_SIM_FX + 3] - slid[:, M_LOAD:M_LOAD + 1] * normal, axis=1)
    touching = slid[:, M_IN_CONTACT] > 0.5
    held = abs(model.contact.pull_off_force()) if model.friction_law != "compressive" else 0.0
    friction_normal = slid[:, M_LOAD] + held
    slipping = touching & (slid[:, M_SLIPPING] > 0.5) & (friction_normal > 0.0)
    ratio = float(np.mean(tangential[slipping] / friction_normal[slipping])) if slipping.any() else math.nan
    model.reset()
    return {"max_depth_m": float(np.max(press_slide[:, M_DEPTH])), "peak_load_N": float(press_slide[k_peak, M_LOAD]),
            "contact_radius_m": float(press_slide[k_peak, M_RADIUS]),
            "pull_off_force_N": float(max(0.0, -np.min(retract[:, M_LOAD]))),
            "mean_friction_force_N": float(np.mean(tangential[touching])) if touching.any() else 0.0,
            "friction_ratio": ratio, "slip_fraction": float(np.mean(slipping))}
