"""Valleys narrower than the tip (tests of the several-contact force): a 20 nm tip over a sinusoid
of 12 nm period, or between two Gaussian bumps 14 nm apart, fitted; the model on them (no
friction, no dent) and the tip height that puts the tip a given depth into the surface."""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.contact.projection import collide
from arsurf.force.cantilever import Cantilever
from arsurf.model import ARModel
from arsurf.scan import synthetic
from arsurf.spline.fit import fit_surface

R = 20e-9  # tip radius, m
PERIOD = 12e-9  # valleys 12 nm apart, narrower than the 40 nm tip
PIXEL = 1e-9
LEVER = Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27)


def valley_surface(kind: str):
    """The fitted surface: ``"sinusoid"`` or ``"bumps"``."""
    if kind == "sinusoid":  # valleys (minima) at x = 9, 21, 33 ... nm (33: far from the fit's boundary effects)
        scan = synthetic.sinusoid(shape=(48, 72), pixel=PIXEL, amplitude=2e-9, period=PERIOD)
    else:  # two Gaussian bumps 14 nm apart, the valley between them at x = 36 nm
        x = np.arange(72) * PIXEL
        bumps = sum(3e-9 * np.exp(-((x - c) / 4e-9) ** 2) for c in (29e-9, 43e-9))
        scan = with_heights(synthetic.sinusoid(shape=(48, 72), pixel=PIXEL, amplitude=0.0, period=PERIOD), bumps)
    return fit_surface(scan)


def with_heights(scan, profile):
    return dataclasses.replace(scan, heights=np.broadcast_to(profile, scan.heights.shape).copy())


def valley_model(kind: str, coupling: float = math.inf, zone_energy: bool = False) -> ARModel:
    """A model on :func:`valley_surface` (a 50 GPa, 0.05 J/m² law; no friction, no dent; its
    contact the energy of the whole tip with ``zone_energy``)."""
    return ARModel(valley_surface(kind), R, MaugisDugdale(R, 50e9, 0.05), LEVER, friction=0.0, deform=False,
                   coupling_stiffness=coupling, zone_energy=zone_energy)


def height_for(kind: str, x_mid: float, depth: float = 0.4e-9) -> float:
    """The tip height (m) at which the tip over ``x_mid`` is ``depth`` into the surface (its
    closest point, along the normal there: a few Newton steps on the collision)."""
    s = valley_surface(kind)
    z = 40e-9
    for _ in range(6):
        c = collide(s, (x_mid, 24e-9, z), R)
        z -= (depth - c.depth) / c.normal[2]
    return z


def pressed_onto(model, c, steps: int = 20) -> None:
    """The tip brought down onto ``c`` (m) from ``steps`` x 0.2 nm above, a tick per 0.2 nm, then
    held there for five ticks."""
    for k in range(steps):
        model.tick((c[0], c[1], c[2] + (steps - k) * 0.2e-9))
    for _ in range(5):
        model.tick(c)
