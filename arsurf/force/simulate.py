"""Synthetic cantilever and detector data: forward simulations for tests, demos and replay.

* :func:`simulate_signals` - forces -> (bending, torsion) -> photodiode signals (and quadrant
  voltages), with optional seeded Gaussian noise.
* :func:`simulate_thermal_trace` - thermally driven deflection of the first flexural mode, an
  exactly discretised stochastic harmonic oscillator (the input of the thermal-noise calibration).
* :func:`simulate_approach_curve` - approach (and retract) deflection signal against piezo z.
* :func:`simulate_wedge_sliding` - vertical and lateral signals while sliding up or down a tilted
  surface (the input of the wedge calibration), from the force balance of [Alabdulmuhsin] Eq. 15-18.

Every generator takes ``seed`` (int or ``numpy.random.Generator``) and is deterministic for a
fixed seed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from arsurf import _validation
from arsurf.errors import ForceError
from arsurf.force.cantilever import Cantilever
from arsurf.force.photodiode import Photodiode, quadrants_from_signals

__all__ = [
    "BOLTZMANN",
    "SimulatedSignals",
    "simulate_approach_curve",
    "simulate_signals",
    "simulate_thermal_trace",
    "simulate_wedge_sliding",
    "wedge_forces",
]

#: Boltzmann constant, J/K (exact, SI 2019).
BOLTZMANN = 1.380649e-23


def _rng(seed) -> np.random.Generator:
    if isinstance(seed, np.random.Generator):
        return seed
    return np.random.default_rng(seed)


def _positive(name: str, value) -> float:
    return _validation.positive(value, name, ForceError)


def _non_negative(name: str, value) -> float:
    return _validation.non_negative(value, name, ForceError)


@dataclass(frozen=True)
class SimulatedSignals:
    """Output of :func:`simulate_signals` (arrays of length n).

    Attributes
    ----------
    bending, torsion : (n,) float, radians (noise-free)
    vertical, lateral : (n,) float, signal units (with noise)
    quadrants : (4, n) float, volts - A, B, C, D of a uniform spot giving the noisy signals
    """

    bending: np.ndarray
    torsion: np.ndarray
    vertical: np.ndarray
    lateral: np.ndarray
    quadrants: np.ndarray


def simulate_signals(
    forces, cantilever: Cantilever, photodiode: Photodiode, *, noise: float = 0.0,
    total: float = 4.0, seed=None,
) -> SimulatedSignals:
    """Forces on the tip -> angles (:meth:`Cantilever.angles`) -> photodiode signals.

    .. math:: V_v = \\Delta\\alpha / S_v + \\epsilon_v, \\qquad V_h = \\Delta\\theta / S_h + \\epsilon_h,
              \\qquad \\epsilon \\sim \\mathcal N(0, \\sigma^2)

    Parameters
    ----------
    forces : (3,) or (n, 3) float, newtons
    cantilever : Cantilever
    photodiode : Photodiode
    noise : float
        Standard deviation sigma of the additive signal noise, in signal units (0: none).
    total : float, volts
        Total light on the cell, for the quadrant voltages.
    seed : int or numpy.random.Generator, optional

    Examples
    --------
    >>> lever = Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27)
    >>> pd = Photodiode(0.02, 0.02)
    >>> sim = simulate_signals([[0.0, 1e-9, 5e-9]], lever, pd, noise=1e-4, seed=1)
    >>> sim.vertical.shape
    (1,)
    """
    f = np.atleast_2d(np.asarray(forces, dtype=np.float64))
    if not isinstance(cantilever, Cantilever) or not isinstance(photodiode, Photodiode):
        raise ForceError("simulate_signals needs a Cantilever and a Photodiode")
    sigma = _non_negative("noise", noise)
    bending, torsion = cantilever.angles(f)
    bending = np.atleast_1d(bending)
    torsion = np.atleast_1d(torsion)
    vertical, lateral = photodiode.signals(bending, torsion)
    if sigma > 0.0:
        rng = _rng(seed)
        vertical = vertical + rng.normal(0.0, sigma, vertical.shape)
        lateral = lateral + rng.normal(0.0, sigma, lateral.shape)
    quads = np.array(quadrants_from_signals(vertical, lateral, total=total, convention=photodiode.convention))
    return SimulatedSignals(bending, torsion, np.asarray(vertical), np.asarray(lateral), quads)


@njit(cache=True)
def _sho_loop(phi, chol, z0, v0, normals, out):
    z = z0
    v = v0
    for i in range(out.shape[0]):
        out[i] = z
        e0 = normals[i, 0]
        e1 = normals[i, 1]
        zn = phi[0, 0] * z + phi[0, 1] * v + chol[0, 0] * e0
        vn = phi[1, 0] * z + phi[1, 1] * v + chol[1, 0] * e0 + chol[1, 1] * e1
        z = zn
        v = vn


def simulate_thermal_trace(
    spring_constant: float, resonance: float, quality: float, sample_rate: float, n: int, *,
    temperature: float = 298.15, correction: float = 0.817, detector_noise: float = 0.0, seed=None,
) -> np.ndarray:
    """Thermal deflection of the first flexural mode as a detector reports it (m), length n.

    A harmonic oscillator m z'' + (m w0/Q) z' + k1 z = xi(t) in thermal equilibrium, sampled at
    ``sample_rate`` with the exact discretisation of the linear SDE:

    .. math::

        x_{i+1} = \\Phi x_i + w_i,\\quad \\Phi = e^{A\\Delta t},\\quad
        w_i \\sim \\mathcal N(0,\\, \\Sigma_\\infty - \\Phi\\Sigma_\\infty\\Phi^T),\\quad
        \\Sigma_\\infty = \\mathrm{diag}(k_B T/k_1,\\; k_B T/m),

    so the stationary variance is exactly k_B T / k_1 at any time step. The mode stiffness is
    ``k1 = spring_constant / correction``: the detector's first-mode mean square is then
    correction * k_B T / k, which is what :func:`arsurf.force.calibration.thermal_spring_constant`
    inverts (Butt & Jaschke 1995: correction 0.817 for an optical lever, 0.971 for the true
    deflection). White detector noise (std ``detector_noise``, m) is added.

    Parameters
    ----------
    spring_constant : float, N/m
    resonance : float, Hz (first-mode frequency f0 < sample_rate / 2)
    quality : float (Q > 0.5)
    sample_rate : float, Hz
    n : int, number of samples
    temperature : float, kelvin
    correction : float in (0, 1]
    detector_noise : float, metres
    seed : int or numpy.random.Generator, optional
    """
    k = _positive("spring_constant", spring_constant)
    f0 = _positive("resonance", resonance)
    q = _positive("quality", quality)
    fs = _positive("sample_rate", sample_rate)
    temp = _positive("temperature", temperature)
    c = _positive("correction", correction)
    if c > 1.0:
        raise ForceError(f"correction must be in (0, 1] (got {correction!r})")
    if q <= 0.5:
        raise ForceError(f"quality must exceed 0.5 (underdamped mode) (got {quality!r})")
    if f0 >= fs / 2:
        raise ForceError(f"resonance {f0:g} Hz must be below the Nyquist frequency {fs / 2:g} Hz")
    if int(n) < 2:
        raise ForceError(f"n must be at least 2 samples (got {n!r})")
    sigma_d = _non_negative("detector_noise", detector_noise)
    from scipy.linalg import expm

    k1 = k / c
    w0 = 2.0 * math.pi * f0
    mass = k1 / w0**2
    a = np.array([[0.0, 1.0], [-(w0**2), -w0 / q]])
    phi = expm(a / fs)
    s_inf = np.diag([BOLTZMANN * temp / k1, BOLTZMANN * temp / mass])
    s_d = s_inf - phi @ s_inf @ phi.T
    s_d = 0.5 * (s_d + s_d.T)
    chol = np.linalg.cholesky(s_d)
    rng = _rng(seed)
    z0 = rng.normal(0.0, math.sqrt(s_inf[0, 0]))
    v0 = rng.normal(0.0, math.sqrt(s_inf[1, 1]))
    normals = rng.standard_normal((int(n), 2))
    out = np.empty(int(n))
    _sho_loop(phi, chol, z0, v0, normals, out)
    if sigma_d > 0.0:
        out += rng.normal(0.0, sigma_d, out.shape)
    return out


def simulate_approach_curve(
    sensitivity: float, contact_point: float, z_start: float, z_stop: float, n: int, *,
    offset: float = 0.0, noise: float = 0.0, retract: bool = False, pull_off: float = 0.0, seed=None,
):
    """Deflection signal against piezo position on a hard sample.

    Out of contact the signal is ``offset``; in contact the deflection equals the piezo advance,
    so :math:`V = \\mathrm{offset} + (z - z_c)/S_n`. With ``retract=True`` the curve returns from
    z_stop to z_start, staying on the contact line until ``pull_off`` (m) below z_c (adhesion),
    then jumping back to the baseline.

    Parameters
    ----------
    sensitivity : float, metres per signal unit (non-zero, may be negative)
    contact_point : float, metres (z_c)
    z_start, z_stop : float, metres; z increases towards the sample
    n : int, samples per branch
    offset, noise : float, signal units (noise is the Gaussian std)
    retract : bool
    pull_off : float, metres (>= 0)

    Returns
    -------
    z, signal : (n,) or (2n,) float
    """
    if not (isinstance(sensitivity, (int, float)) and math.isfinite(sensitivity) and sensitivity != 0.0):
        raise ForceError(f"sensitivity must be finite and non-zero (got {sensitivity!r})")
    if not z_stop > z_start:
        raise ForceError(f"z_stop must exceed z_start (got {z_start!r}, {z_stop!r}); z grows towards the sample")
    sigma = _non_negative("noise", noise)
    po = _non_negative("pull_off", pull_off)
    z = np.linspace(z_start, z_stop, int(n))
    s = offset + np.maximum(z - contact_point, 0.0) / sensitivity
    if retract:
        zr = z[::-1]
        sr = offset + np.where(zr > contact_point - po, (zr - contact_point) / sensitivity, 0.0)
        z = np.concatenate([z, zr])
        s = np.concatenate([s, sr])
    if sigma > 0.0:
        s = s + _rng(seed).normal(0.0, sigma, s.shape)
    return z, s


def wedge_forces(load, tilt: float, friction: float, adhesion: float, direction: str):
    """Lab-frame normal and lateral force on the tip sliding on a tilted surface.

    The surface rises along +y at angle theta; N is the contact (repulsive) force along the surface
    normal and f = mu N + A the friction ([Alabdulmuhsin] Eq. 15-18), opposing the motion. Sliding up
    (motion +y) and down (motion -y):

    .. math::

        F_z^{up} = N\\cos\\theta - f\\sin\\theta,\\quad F_y^{up} = -(N\\sin\\theta + f\\cos\\theta),\\\\
        F_z^{down} = N\\cos\\theta + f\\sin\\theta,\\quad F_y^{down} = -N\\sin\\theta + f\\cos\\theta.

    Parameters
    ----------
    load : array, newtons (N >= 0)
    tilt : float, radians in (0, pi/2)
    friction : float (mu >= 0)
    adhesion : float, newtons (A)
    direction : {"up", "down"}

    Returns
    -------
    normal_force, lateral_force : arrays, newtons (F_z, F_y)
    """
    n = np.asarray(load, dtype=np.float64)
    f = friction * n + adhesion
    ct, st = math.cos(tilt), math.sin(tilt)
    if direction == "up":
        return n * ct - f * st, -(n * st + f * ct)
    if direction == "down":
        return n * ct + f * st, -n * st + f * ct
    raise ForceError(f"direction must be 'up' or 'down' (got {direction!r})")


def simulate_wedge_sliding(
    loads, tilt: float, friction: float, lateral_gain: float, normal_gain: float, direction: str, *,
    adhesion: float = 0.0, noise_vertical: float = 0.0, noise_lateral: float = 0.0,
    lateral_offset: float = 0.0, seed=None,
):
    """Vertical and lateral signals while sliding up or down a tilted surface.

    :math:`V_v = F_z / (k S_n)`, :math:`V_h = F_y / G_l + V_{h,0}` with the forces of
    :func:`wedge_forces`, plus Gaussian noise.

    Parameters
    ----------
    loads : array, newtons (contact force N along the sweep)
    tilt, friction, adhesion : see :func:`wedge_forces`
    lateral_gain : float, N per signal unit (G_l, non-zero)
    normal_gain : float, N per signal unit (k S_n, non-zero)
    direction : {"up", "down"}
    noise_vertical, noise_lateral : float, signal units
    lateral_offset : float, signal units (zero offset of the lateral channel)

    Returns
    -------
    vertical, lateral : arrays
    """
    for name, value in (("lateral_gain", lateral_gain), ("normal_gain", normal_gain)):
        if not (math.isfinite(value) and value != 0.0):
            raise ForceError(f"{name} must be finite and non-zero (got {value!r})")
    fz, fy = wedge_forces(loads, tilt, friction, adhesion, direction)
    vertical = fz / normal_gain
    lateral = fy / lateral_gain + lateral_offset
    rng = _rng(seed)
    sv = _non_negative("noise_vertical", noise_vertical)
    sh = _non_negative("noise_lateral", noise_lateral)
    if sv > 0.0:
        vertical = vertical + rng.normal(0.0, sv, vertical.shape)
    if sh > 0.0:
        lateral = lateral + rng.normal(0.0, sh, lateral.shape)
    return vertical, lateral
