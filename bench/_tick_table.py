"""The tick table shared by bench/deformation.py and bench/haptic_loop.py (issue 28).

One rough surface in physical units - Gaussian roughness correlated over 6 nm (or 3 pixels
where the pixels are coarser), 0.5 nm rms: slopes ~0.1 - scanned on 256 x 256 pixels at each
pitch and fitted (:func:`arsurf.scan.synthetic.rough`); a tip of radius R pressed ``depth`` below touching
the surface slides 0.01 nm per tick, dent on.
"""
from __future__ import annotations

import numpy as np

from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.force.cantilever import Cantilever
from arsurf.model import ARModel
from arsurf.scan.synthetic import rough
from arsurf.spline.fit import fit_surface

SIZE = 256
#: the coarse default grid (each run well under 2 min on a shared 2-core machine) and --full
PITCHES_NM = (0.1, 0.25, 0.5, 2.0, 8.0)
TIPS_NM = (2.0, 20.0, 50.0)
DEPTHS_NM = (0.3, 1.0)
FULL_PITCHES_NM = (0.1, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0)
FULL_TIPS_NM = (2.0, 5.0, 10.0, 20.0, 50.0)
FULL_DEPTHS_NM = (0.1, 0.3, 1.0, 2.0)
STEP = 0.01e-9  # tip slide per tick, m


def rough_surface(pitch: float, seed: int = 0):
    """The 256 x 256 scan at ``pitch`` (m per pixel), fitted (:func:`arsurf.scan.synthetic.rough`)."""
    return fit_surface(rough((SIZE, SIZE), pitch, rms=0.5e-9, correlation_length=max(6e-9, 3.0 * pitch), seed=seed))


def model_on(surface, tip: float, deform: bool = True) -> ARModel:
    """A polystyrene-like sample (E* 5 GPa) under a tip of radius ``tip``, w = 0.05 J/m^2."""
    return ARModel(surface, tip, MaugisDugdale(tip, 5e9, 0.05), Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27),
                   deform=deform)


def start(surface, tip: float, depth: float) -> np.ndarray:
    """The tip centre ``depth`` below touching the highest rest point within R of the middle."""
    (u0, u1), (v0, v1) = surface.domain
    x, y = 0.5 * (u0 + u1) - 40 * STEP, 0.5 * (v0 + v1)
    g = np.linspace(-tip, tip, 41)
    dx, dy = np.meshgrid(g, g)
    d2 = dx * dx + dy * dy
    near = d2 < tip * tip
    z = surface.evaluate(x + dx[near], y + dy[near])[:, 2]
    top = np.max(z + np.sqrt(tip * tip - d2[near]))
    return np.array([x, y, top - depth])
