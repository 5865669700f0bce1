"""3D tip force from the two measured angles (bending, torsion): contact-normal and motion methods.

The optical lever measures only (docs/design.rst, "Force from the two angles"; [SplineAR] Eq. 1-2;
frame of :mod:`arsurf.force.cantilever`)

.. math::

    \\Delta\\theta = c F_y, \\qquad \\Delta\\alpha = g\\,(F_z + \\kappa F_x), \\qquad
    g = \\frac{l^2}{2EI},\\; \\kappa = \\frac{2a}{l},\\; c = \\frac{a}{k_{t\\phi}}.

A third equation comes from the contact geometry ([SplineAR] Eq. 3, completed in docs/design.rst, "Force from the two
angles"): the force lies in the plane of the contact normal n and the friction direction f, which is tangent to
the surface and opposite to the horizontal tip motion v:

.. math::

    f = (-v_x, -v_y, f_z),\\; f\\cdot n = 0 \\Rightarrow f_z = \\frac{v_x n_x + v_y n_y}{n_z},
    \\qquad p = n \\times f, \\qquad F \\cdot p = 0.

With :math:`\\tau = \\Delta\\theta / c` and :math:`\\beta = \\Delta\\alpha / g` (the force
equivalents of the two signals) and unit p, the row-scaled system and its closed-form solution are

.. math::

    \\begin{pmatrix} 0 & 1 & 0 \\\\ \\kappa & 0 & 1 \\\\ p_x & p_y & p_z \\end{pmatrix} F =
    \\begin{pmatrix} \\tau \\\\ \\beta \\\\ 0 \\end{pmatrix},\\quad
    F_y = \\tau,\\; F_x = -\\frac{p_y \\tau + p_z \\beta}{p_x - \\kappa p_z},\\;
    F_z = \\beta - \\kappa F_x.

The determinant :math:`p_x - \\kappa p_z` vanishes on the singular direction
:math:`p_x = \\kappa p_z` (e.g. sliding along the beam axis on a flat sample). In the kernel the
division by n_z is avoided by using :math:`n_z f`, which has the same direction.

Degenerate cases are flagged (:class:`DecouplingFlag`) and handled by a documented fallback,
never returned as garbage:

* ``NO_MOTION`` - horizontal speed below ``min_speed``: no friction direction.
* ``STEEP_NORMAL`` - n_z below ``min_normal_z`` (a wall; the along-z projection of v breaks down).
* ``SINGULAR`` - ``|p_x - kappa p_z| <= 1e-10`` (the three rows are dependent).
* ``ILL_CONDITIONED`` - the 1-norm condition number of the scaled 3x3 system exceeds
  ``max_condition``: a relative signal error e may become up to about cond * e in the force.

Fallback ``"normal_plus_torsion"``: the force is taken along the contact normal plus a lateral
force that explains the torsion, F = N n + T e_y, solved exactly from the two signals
(:math:`N = \\beta / (n_z + \\kappa n_x)`, :math:`T = \\tau - N n_y`); it reproduces both measured
angles. If that 2x2 system is itself ill-conditioned (``|n_z + kappa n_x| * max_condition < 1``)
the flag ``FALLBACK_DEGENERATE`` is added and the force is ``"bending_only"``: F = (0, tau, beta),
the classical AFM reading (all bending attributed to F_z). Invalid kernel input (NaN, non-unit
normal) gives ``INVALID_INPUT`` and a zero force.
"""
from __future__ import annotations

import enum
import functools
import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from arsurf._layout import Layout
from arsurf.errors import ForceError
from arsurf.force.cantilever import Cantilever

__all__ = [
    "DEFAULT_MAX_CONDITION",
    "DEFAULT_MIN_NORMAL_Z",
    "DEFAULT_MIN_SPEED",
    "DECOUPLING_OUT",
    "DECOUPLING_PARAMS",
    "FADE_CONDITION",
    "FADE_STRENGTH",
    "MEASURED_PARAMS",
    "MEASURED_SCRATCH",
    "DecouplingFlag",
    "ForceEstimate",
    "bending_only_kernel",
    "blended_decouple_kernel",
    "decouple",
    "decouple_by_motion",
    "decouple_kernel",
    "decouple_many",
    "decouple_many_kernel",
    "directional_noise_kernel",
    "decoupling_parameters",
    "method_from_status",
]

# ---- tolerances (one place; see the module docstring for what each one guards) ----------------
#: Horizontal tip speeds at or below this (m/s) count as standing still: 1 pm/s is far below any
#: deliberate scanner motion and at the level of piezo creep, so no friction direction exists.
DEFAULT_MIN_SPEED = 1e-12
#: Normals with n_z below this are walls (slope > 89.4 deg): the friction direction, obtained by
#: projecting the horizontal motion along z onto the tangent plane, is no longer meaningful.
DEFAULT_MIN_NORMAL_Z = 1e-2
#: Largest accepted 1-norm condition number of the row-scaled 3x3 system. On a flat sample it is
#: about 2/|sin(phi)| for motion at angle phi to the beam axis, so 1e3 accepts phi > ~0.1 deg.
DEFAULT_MAX_CONDITION = 1e3
#: |det| at or below this marks the singular direction p_x = kappa p_z (cond >~ 1e10).
SINGULAR_TOLERANCE = 1e-10
#: Kernel check that the normal is unit length.
UNIT_TOLERANCE = 1e-6


class DecouplingFlag(enum.IntFlag):
    """Bits of the decoupling status (kernel return value, :attr:`ForceEstimate.flags`)."""

    NONE = 0
    NO_MOTION = 1
    STEEP_NORMAL = 2
    SINGULAR = 4
    ILL_CONDITIONED = 8
    FALLBACK_DEGENERATE = 16
    INVALID_INPUT = 32


# the bits as the kernels use them
_NO_MOTION = int(DecouplingFlag.NO_MOTION)
_STEEP_NORMAL = int(DecouplingFlag.STEEP_NORMAL)
_SINGULAR = int(DecouplingFlag.SINGULAR)
_ILL_CONDITIONED = int(DecouplingFlag.ILL_CONDITIONED)
_FALLBACK_DEGENERATE = int(DecouplingFlag.FALLBACK_DEGENERATE)
_INVALID_INPUT = int(DecouplingFlag.INVALID_INPUT)
_DEGENERATE = _NO_MOTION | _STEEP_NORMAL | _SINGULAR | _ILL_CONDITIONED
_FLAGS = [DecouplingFlag(i) for i in range(64)]  # status -> flag, prebuilt (IntFlag() costs ~1 us)

#: the kernel's parameter vector (:func:`decoupling_parameters`): g (rad/N), kappa, c (rad/N), and
#: the three degeneracy thresholds
DECOUPLING_PARAMS = Layout("decoupling parameters", [
    ("bending_compliance", 1), ("coupling", 1), ("torsion_compliance", 1), ("min_speed", 1), ("min_normal_z", 1),
    ("max_condition", 1)])
#: what :func:`decouple_kernel` writes: the force (N) and the condition number of the system solved
DECOUPLING_OUT = Layout("decoupling output", [("force", 3), ("condition", 1)])
#: the parameters of :func:`blended_decouple_kernel`: the decoupling's, then the rms noise (rad) on
#: each measured angle
MEASURED_PARAMS = DECOUPLING_PARAMS.extended("measured-force parameters", [("signal_noise", 1)])
#: what :func:`blended_decouple_kernel` writes: the blend (a decoupling output), then the fallback's
MEASURED_SCRATCH = Layout("measured-force output", [("blend", DECOUPLING_OUT.size), ("fallback", DECOUPLING_OUT.size)])
# the offsets as the kernels use them
P_BENDING_COMPLIANCE = DECOUPLING_PARAMS.offset("bending_compliance")
P_COUPLING = DECOUPLING_PARAMS.offset("coupling")
P_TORSION_COMPLIANCE = DECOUPLING_PARAMS.offset("torsion_compliance")
P_MIN_SPEED = DECOUPLING_PARAMS.offset("min_speed")
P_MIN_NORMAL_Z = DECOUPLING_PARAMS.offset("min_normal_z")
P_MAX_CONDITION = DECOUPLING_PARAMS.offset("max_condition")
P_SIGNAL_NOISE = MEASURED_PARAMS.offset("signal_noise")
O_FORCE, O_CONDITION = DECOUPLING_OUT.offset("force"), DECOUPLING_OUT.offset("condition")
_BLEND, _FALLBACK = MEASURED_SCRATCH.offset("blend"), MEASURED_SCRATCH.offset("fallback")
_OUT_SIZE = DECOUPLING_OUT.size


@njit(cache=True, inline="always")
def _plane_normal(nx, ny, nz, vx, vy):
    """Normal p of the plane of the contact normal n and the friction direction (along -v in the
    tangent plane): :math:`n_z f = (-v_x n_z, -v_y n_z, v_x n_x + v_y n_y)`, :math:`p = n \\times (n_z f)`;
    returns (p_x, p_y, p_z, |p|), not normalised."""
    fx = -vx * nz
    fy = -vy * nz
    fz = vx * nx + vy * ny
    px = ny * fz - nz * fy
    py = nz * fx - nx * fz
    pz = nx * fy - ny * fx
    return px, py, pz, math.sqrt(px * px + py * py + pz * pz)


@njit(cache=True)
def decouple_kernel(bending, torsion, nx, ny, nz, vx, vy, params, out):
    """Contact-normal decoupling of one sample; writes (F_x, F_y, F_z, condition) into ``out``.

    Parameters
    ----------
    bending, torsion : float, radians
    nx, ny, nz : float
        Unit contact normal (out of the sample).
    vx, vy : float, m/s
        Horizontal tip velocity (v_z is not used: the tip follows the surface).
    params : (6,) float64
        From :func:`decoupling_parameters`.
    out : (4,) float64
        Receives F_x, F_y, F_z (N) and the 1-norm condition number of the system used
        (inf when none was solved).

    Returns
    -------
    int
        Status bits (:class:`DecouplingFlag`); 0 means the contact-normal solution.
    """
    g = params[P_BENDING_COMPLIANCE]
    kappa = params[P_COUPLING]
    c = params[P_TORSION_COMPLIANCE]
    min_speed = params[P_MIN_SPEED]
    min_nz = params[P_MIN_NORMAL_Z]
    max_cond = params[P_MAX_CONDITION]
    out[O_FORCE] = 0.0
    out[O_FORCE + 1] = 0.0
    out[O_FORCE + 2] = 0.0
    out[O_CONDITION] = np.inf
    if not (
        math.isfinite(bending) and math.isfinite(torsion) and math.isfinite(nx) and math.isfinite(ny)
        and math.isfinite(nz) and math.isfinite(vx) and math.isfinite(vy)
    ):
        return _INVALID_INPUT
    nn = nx * nx + ny * ny + nz * nz
    if not (abs(nn - 1.0) <= 2.0 * UNIT_TOLERANCE):
        return _INVALID_INPUT
    beta = bending / g  # F_z + kappa F_x
    tau = torsion / c  # F_y
    status = 0
    if not (vx * vx + vy * vy > min_speed * min_speed):
        status |= _NO_MOTION
    if not (nz >= min_nz):
        status |= _STEEP_NORMAL
    if status == 0:
        px, py, pz, pn = _plane_normal(nx, ny, nz, vx, vy)  # then normalised
        px /= pn
        py /= pn
        pz /= pn
        det = px - kappa * pz
        ad = abs(det)
        if ad <= SINGULAR_TOLERANCE:
            status |= _SINGULAR
        else:
            # 1-norm condition: ||M||_1 * ||adj(M)||_1 / |det|
            akappa = abs(kappa)
            norm_m = max(akappa + abs(px), max(1.0 + abs(py), 1.0 + abs(pz)))
            c0 = abs(py) * (1.0 + akappa) + ad
            c1 = abs(pz) + abs(px)
            c2 = 1.0 + akappa
            cond = norm_m * max(c0, max(c1, c2)) / ad
            if cond > max_cond:
                status |= _ILL_CONDITIONED
            else:
                fxs = -(py * tau + pz * beta) / det
                out[O_FORCE] = fxs
                out[O_FORCE + 1] = tau
                out[O_FORCE + 2] = beta - kappa * fxs
                out[O_CONDITION] = cond
                return 0
    # fallback: F = N n + T e_y  (force along the normal plus the measured torsion)
    den = nz + kappa * nx
    aden = abs(den)
    if aden * max_cond >= 1.0:
        big_n = beta / den
        out[O_FORCE] = big_n * nx
        out[O_FORCE + 1] = tau
        out[O_FORCE + 2] = big_n * nz
        # 1-norm condition of [[n_y, 1], [den, 0]]
        out[O_CONDITION] = max(abs(ny) + aden, 1.0) * max(1.0, (1.0 + abs(ny)) / aden)
        return status
    out[O_FORCE] = 0.0
    out[O_FORCE + 1] = tau
    out[O_FORCE + 2] = beta
    out[O_CONDITION] = 1.0
    return status | _FALLBACK_DEGENERATE


@njit(cache=True)
def directional_noise_kernel(nx, ny, nz, vx, vy, params, sigma_bending, sigma_torsion):
    """Standard deviation (N) of the contact-normal solution's F_x from independent noise on the
    two angles, ``sigma_bending`` and ``sigma_torsion`` (rad rms); 0 where it is not solved.

    First-order propagation through the closed form (module docstring), with
    :math:`\\sigma_\\tau = \\sigma_\\theta / c`, :math:`\\sigma_\\beta = \\sigma_\\alpha / g`:

    .. math::

        \\sigma_{F_x} = \\frac{\\sqrt{p_y^2 \\sigma_\\tau^2 + p_z^2 \\sigma_\\beta^2}}{|p_x - \\kappa p_z|},
        \\qquad \\delta F_y = \\delta\\tau, \\quad \\delta F_z = \\delta\\beta - \\kappa\\,\\delta F_x .

    It is the exact noise gain the 1-norm condition number bounds (``cond * |noise| / |signal| *
    |F|``): it grows as 1/|det| towards the singular direction. Same inputs as
    :func:`decouple_kernel` (no validation: call it where that returned 0)."""
    g = params[P_BENDING_COMPLIANCE]
    kappa = params[P_COUPLING]
    c = params[P_TORSION_COMPLIANCE]
    px, py, pz, pn = _plane_normal(nx, ny, nz, vx, vy)
    if not pn > 0.0:
        return 0.0
    ad = abs(px - kappa * pz) / pn
    if not ad > SINGULAR_TOLERANCE:
        return 0.0
    st = py / pn * (sigma_torsion / c)
    sb = pz / pn * (sigma_bending / g)
    return math.sqrt(st * st + sb * sb) / ad


#: The measured force of a contact (:func:`blended_decouple_kernel`) fades from the no-motion
#: fallback (normal + torsion, plus the friction model's share along the beam axis per unit load)
#: to the directional solution as the friction strength |F_t| / f_k (f_k the kinetic limit,
#: mu_k N) grows over this band, and no switch makes the force jump
FADE_STRENGTH = (0.05, 0.25)
#: ... and back to the fallback as the condition number of the directional system grows over this
#: band (log scale; the decoupling refuses above 1e3): noise gain and the switch both fade out.
#: In the beam's plane (x, z) friction and normal load both bend the lever, so the fallback takes the
#: friction's share there from the friction model, r = (F_t,x, F_t,z) / P, and solves the one load
#: that reproduces the bending: F = N (n + r_x e_x + r_z e_z) + T e_y,
#: N = (theta/g) / (n_z + r_z + kappa (n_x + r_x)). Without friction (r = 0) it is the decoupling's
#: no-motion answer; with it, a slide whose directional system turns
#: singular keeps its friction instead of dropping it for a few ticks (a dip the hand felt).
FADE_CONDITION = (100.0, 1000.0)
#: ... and, below that edge, by how much each answer can be trusted. The two solutions agree on
#: F_y = tau and on F_z + kappa F_x = beta (both reproduce the angles); they differ only in how the
#: beam-plane bending is split, i.e. in F_x. The directional F_x carries the signal noise times
#: the system's noise gain, sigma_D = sqrt(p_y^2 sigma_tau^2 + p_z^2 sigma_beta^2) / |p_x - kappa p_z|
#: (:func:`directional_noise_kernel`; what cond * noise / signal * |F| bounds), which grows without
#: bound as the friction direction sweeps through the beam axis (a stuck contact starting to slide
#: along x); the fallback's F_x carries its model error, the friction model's share, which can be
#: wrong by at most the friction the contact can hold, sigma_B = mu_s P. Weighing the two by their
#: inverse variances (minimum-variance combination of two independent estimates of F_x),
#:
#:     w_noise = sigma_B^2 / (sigma_B^2 + sigma_D^2),
#:
#: keeps the measured friction while the directional error is below the friction scale and lets
#: the fallback take over where noise would dominate; w_noise is continuous (sigma_D is, away from
#: the refused band the condition fade covers) and 1 without noise (the fade above is then all).
#: sigma_D uses the parameter ``signal_noise`` (rad rms on each angle, :data:`MEASURED_PARAMS`).
#: The status gets the NO_MOTION bit (fallback mixed in) where one of the two fades is below 1, or
#: where the noise makes the fallback the better estimate (sigma_D > sigma_B, w_noise < 1/2); a
#: well-conditioned slide stays flagged 0, its w_noise ~ 1.


@njit(cache=True)
def blended_decouple_kernel(bending, torsion, nx, ny, nz, fx, fy, strength, share_x, share_z, friction_limit,
                            mx, my, mz, params, out):
    """The measured force of a contact: the directional solution (friction direction ``(fx, fy)``)
    faded into the no-motion fallback as the friction weakens, the system loses conditioning or
    the noise outweighs the friction (:data:`FADE_STRENGTH`, :data:`FADE_CONDITION`); both
    reproduce the two measured angles exactly, so every blend does too.

    Both are taken relative to the model's force ``(mx, my, mz)`` :math:`F_m` (N): what the angles
    say beyond the model's own angles is decoupled and added to it,
    :math:`F = F_m + D(s - M F_m)` (D the blend, linear in the signals s; M the cantilever's map
    from force to angles). Where :math:`F_m` is of the decoupling's form - one contact, its
    friction in its tangent plane, so :math:`F_m\\cdot p = 0` and :math:`F_m = P(n + r) + F_{t,y} e_y`
    - this is the plain decoupling of s, exactly (the solutions are unique). Under several contacts
    n is their summed normal and the friction lies in the closest contact's tangent plane, so
    :math:`F_m` is of neither form, and the plain decoupling put the difference into F_x with the
    gain :math:`1/|p_x - \\kappa p_z|` or :math:`1/|n_z + r_z + \\kappa (n_x + r_x)|`: a tip sliding
    along a wall on two contacts was measured at F_x = +100 and -137 nN where the model's was -14
    and -29 nN (a 10 nm/s slide, 15 % of the force above 100 Hz, 16 reversals). Now the model's
    force exactly when the angles are its own, and what noise or a real lever adds, decoupled.

    ``strength`` :math:`\\lVert F_t\\rVert / f_k` of the friction (:math:`f_k = \\mu_k N`),
    ``share_x``, ``share_z`` its components along x and z per unit load (the fallback's beam-plane
    friction), ``friction_limit``
    :math:`f_s = \\mu_s N` (N, sigma_B); ``params`` (:data:`MEASURED_PARAMS`); writes ``out``
    (:data:`MEASURED_SCRATCH`): the force and condition of the blend first. Returns the status
    bits (:class:`DecouplingFlag`)."""
    bending -= params[P_BENDING_COMPLIANCE] * (mz + params[P_COUPLING] * mx)  # what the model's angles miss
    torsion -= params[P_TORSION_COMPLIANCE] * my
    ds = decouple_kernel(bending, torsion, nx, ny, nz, fx, fy, params, out[_BLEND:_BLEND + _OUT_SIZE])
    w = 0.0
    flag = False  # the fallback is reported (NO_MOTION) where a fade applies or it outweighs
    if ds == 0:
        w = min(max((strength - FADE_STRENGTH[0]) / (FADE_STRENGTH[1] - FADE_STRENGTH[0]), 0.0), 1.0)
        w *= min(max(math.log(FADE_CONDITION[1] / out[_BLEND + O_CONDITION])
                     / math.log(FADE_CONDITION[1] / FADE_CONDITION[0]), 0.0), 1.0)
        flag = w < 1.0
        if w > 0.0:  # inverse-variance weight of the two F_x estimates (FADE_CONDITION comment)
            noise = params[P_SIGNAL_NOISE]
            var_d = directional_noise_kernel(nx, ny, nz, fx, fy, params, noise, noise) ** 2
            if var_d > 0.0:
                var_b = friction_limit ** 2
                w *= var_b / (var_b + var_d)
                flag = flag or var_d > var_b
    if w < 1.0:
        fb = out[_FALLBACK:_FALLBACK + _OUT_SIZE]
        d0 = decouple_kernel(bending, torsion, nx, ny, nz, 0.0, 0.0, params, fb)
        den = nz + share_z + params[P_COUPLING] * (nx + share_x)
        if (share_x != 0.0 or share_z != 0.0) and d0 & _FALLBACK_DEGENERATE == 0 \
                and abs(den) * params[P_MAX_CONDITION] >= 1.0:
            big_n = bending / (params[P_BENDING_COMPLIANCE] * den)
            fb[O_FORCE] = big_n * (nx + share_x)
            fb[O_FORCE + 2] = big_n * (nz + share_z)
        for j in range(3):
            out[_BLEND + O_FORCE + j] = w * out[_BLEND + O_FORCE + j] + (1.0 - w) * fb[O_FORCE + j]
        if w == 0.0:
            ds = d0
            out[_BLEND + O_CONDITION] = fb[O_CONDITION]
        elif flag:
            ds |= _NO_MOTION
    if not ds & _INVALID_INPUT:  # (invalid input: a zero force, as the plain decoupling's)
        out[_BLEND + O_FORCE] += mx
        out[_BLEND + O_FORCE + 1] += my
        out[_BLEND + O_FORCE + 2] += mz
    return ds


@njit(cache=True)
def bending_only_kernel(bending, torsion, params, out):
    """The classical AFM reading F = (0, tau, beta) (all bending taken as F_z), where there is no
    contact normal to decouple with; writes ``out`` (:data:`DECOUPLING_OUT`, condition 1) and
    returns ``FALLBACK_DEGENERATE``."""
    out[O_FORCE] = 0.0
    out[O_FORCE + 1] = torsion / params[P_TORSION_COMPLIANCE]
    out[O_FORCE + 2] = bending / params[P_BENDING_COMPLIANCE]
    out[O_CONDITION] = 1.0
    return _FALLBACK_DEGENERATE


@njit(cache=True)
def decouple_many_kernel(bending, torsion, normals, velocities, params, forces, condition, status):
    """Loop of :func:`decouple_kernel` over n samples (replay); fills ``forces`` (n, 3),
    ``condition`` (n,) and ``status`` (n,) int64 in place."""
    out = np.empty(_OUT_SIZE)
    for i in range(bending.shape[0]):
        s = decouple_kernel(
            bending[i], torsion[i], normals[i, 0], normals[i, 1], normals[i, 2],
            velocities[i, 0], velocities[i, 1], params, out,
        )
        forces[i, 0] = out[O_FORCE]
        forces[i, 1] = out[O_FORCE + 1]
        forces[i, 2] = out[O_FORCE + 2]
        condition[i] = out[O_CONDITION]
        status[i] = s


def method_from_status(status: int, motion: bool = False) -> str:
    """Name of the model that produced the force for a kernel status.

    ``"contact_normal"`` (or ``"motion_direction"`` for :func:`decouple_by_motion`),
    ``"normal_plus_torsion"``, ``"bending_only"`` or ``"none"`` (invalid input).
    """
    status = int(status)
    if status & _INVALID_INPUT:
        return "none"
    if status & _FALLBACK_DEGENERATE:
        return "bending_only"
    if status & _DEGENERATE:
        # with the flat normal of the motion method, N e_z + T e_y is the bending-only reading
        return "bending_only" if motion else "normal_plus_torsion"
    return "motion_direction" if motion else "contact_normal"


@dataclass(frozen=True)
class ForceEstimate:
    """A decoupled 3D force and how it was obtained.

    Attributes
    ----------
    force : (3,) float64, newtons
        (F_x, F_y, F_z) on the tip apex, cantilever frame.
    method : str
        ``"contact_normal"``, ``"motion_direction"``, ``"normal_plus_torsion"`` or ``"bending_only"``.
    flags : DecouplingFlag
        Why a fallback was used (``DecouplingFlag.NONE`` if none).
    condition : float
        1-norm condition number of the linear system that produced ``force``.
    """

    force: np.ndarray
    method: str
    flags: DecouplingFlag
    condition: float

    @property
    def ok(self) -> bool:
        """True when the primary method solved a well-conditioned system (no flag)."""
        return self.flags == DecouplingFlag.NONE


def decoupling_parameters(
    cantilever: Cantilever,
    min_speed: float = DEFAULT_MIN_SPEED,
    min_normal_z: float = DEFAULT_MIN_NORMAL_Z,
    max_condition: float = DEFAULT_MAX_CONDITION,
    coupling: float | None = None,
) -> np.ndarray:
    """Validated parameter vector (6,) for :func:`decouple_kernel` (build once, reuse in the loop).

    Parameters
    ----------
    cantilever : Cantilever
    min_speed : float, m/s (>= 0)
    min_normal_z : float in [0, 1)
    max_condition : float (>= 1)
    coupling : float, optional
        Override of kappa = 2a/l (see :func:`decouple_by_motion`).

    Examples
    --------
    >>> lever = Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27)
    >>> params = decoupling_parameters(lever)
    >>> out = np.empty(DECOUPLING_OUT.size)
    >>> decouple_kernel(*lever.angles([1e-9, 2e-9, 5e-9]), 0.0, 0.0, 1.0, 0.0, 1e-6, params, out)
    0
    """
    if not isinstance(cantilever, Cantilever):
        raise ForceError(f"cantilever must be an arsurf Cantilever (got {type(cantilever).__name__})")
    _finite_scalar("min_speed", min_speed)
    if min_speed < 0.0:
        raise ForceError(f"min_speed must be >= 0 m/s (got {min_speed!r})")
    _finite_scalar("min_normal_z", min_normal_z)
    if not 0.0 <= min_normal_z < 1.0:
        raise ForceError(f"min_normal_z must be in [0, 1) (got {min_normal_z!r}); it is the smallest accepted n_z")
    _finite_scalar("max_condition", max_condition)
    if max_condition < 1.0:
        raise ForceError(f"max_condition must be >= 1 (got {max_condition!r}); a condition number is never below 1")
    g, kappa, c = cantilever.kernel_parameters()
    if coupling is not None:
        _finite_scalar("coupling", coupling)
        if coupling < 0.0:
            raise ForceError(f"coupling must be >= 0 (got {coupling!r}); it is a lever arm over the length")
        kappa = float(coupling)
    return np.array([g, kappa, c, float(min_speed), float(min_normal_z), float(max_condition)])


@functools.lru_cache(maxsize=64)
def _cached_parameters(cantilever, min_speed, min_normal_z, max_condition, coupling) -> np.ndarray:
    """:func:`decoupling_parameters` memoised for the per-call API (Cantilever is frozen and hashable)."""
    return decoupling_parameters(cantilever, min_speed, min_normal_z, max_condition, coupling)


def _parameters(cantilever, min_speed, min_normal_z, max_condition, coupling) -> np.ndarray:
    if not isinstance(cantilever, Cantilever):
        raise ForceError(f"cantilever must be an arsurf Cantilever (got {type(cantilever).__name__})")
    try:
        return _cached_parameters(cantilever, min_speed, min_normal_z, max_condition, coupling)
    except TypeError:  # unhashable threshold: validate without the cache (raises a clear ForceError)
        return decoupling_parameters(cantilever, min_speed, min_normal_z, max_condition, coupling)


def _finite_scalar(name: str, value) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ForceError(f"{name} must be a real number (got {value!r})")
    if not math.isfinite(value):
        raise ForceError(f"{name} must be finite (got {value!r}); drop or interpolate NaN samples before decoupling")
    return float(value)


def _check_normal(normal) -> tuple[float, float, float]:
    n = np.asarray(normal, dtype=np.float64)
    if n.shape != (3,):
        raise ForceError(f"normal must have shape (3,) (got {n.shape}); it is the unit contact normal (n_x, n_y, n_z)")
    nx, ny, nz = n.tolist()
    if not (math.isfinite(nx) and math.isfinite(ny) and math.isfinite(nz)):
        raise ForceError(f"normal must be finite (got {n.tolist()})")
    norm = math.sqrt(nx * nx + ny * ny + nz * nz)
    if norm == 0.0:
        raise ForceError("normal is the zero vector; pass the unit contact normal from arsurf.collide()")
    if abs(norm - 1.0) > UNIT_TOLERANCE:
        raise ForceError(
            f"normal must be a unit vector (got |n| = {norm:.9g}); pass n / np.linalg.norm(n)"
        )
    return nx, ny, nz


def _check_velocity(velocity) -> tuple[float, float]:
    v = np.asarray(velocity, dtype=np.float64)
    if v.shape not in ((2,), (3,)):
        raise ForceError(f"velocity must have shape (2,) or (3,) (got {v.shape}); it is the tip velocity in m/s")
    vals = v.tolist()
    if not all(math.isfinite(x) for x in vals):
        raise ForceError(f"velocity must be finite (got {vals})")
    return vals[0], vals[1]


def _estimate(out: np.ndarray, status: int, motion: bool) -> ForceEstimate:
    force = out[DECOUPLING_OUT.slice("force")].copy()
    force.setflags(write=False)
    return ForceEstimate(force, method_from_status(status, motion), _FLAGS[status], float(out[O_CONDITION]))


def decouple(
    bending: float,
    torsion: float,
    normal,
    velocity,
    cantilever: Cantilever,
    *,
    min_speed: float = DEFAULT_MIN_SPEED,
    min_normal_z: float = DEFAULT_MIN_NORMAL_Z,
    max_condition: float = DEFAULT_MAX_CONDITION,
) -> ForceEstimate:
    """3D tip force from bending and torsion using the contact normal ([SplineAR]; docs/design.rst,
    "Force from the two angles").

    Solves {torsion, bending, F . p = 0} with p = n x f (module docstring); degenerate cases
    are flagged and answered by the documented fallback.

    Parameters
    ----------
    bending, torsion : float, radians
        Measured angles (e.g. :meth:`Photodiode.angles`), zero-force offsets removed.
    normal : (3,) float
        Unit contact normal pointing out of the sample (``Contact.normal``).
    velocity : (2,) or (3,) float, m/s
        Tip velocity relative to the sample; only (v_x, v_y) is used.
    cantilever : Cantilever
    min_speed, min_normal_z, max_condition : float
        Degeneracy thresholds (defaults :data:`DEFAULT_MIN_SPEED`, :data:`DEFAULT_MIN_NORMAL_Z`,
        :data:`DEFAULT_MAX_CONDITION`).

    Returns
    -------
    ForceEstimate

    Raises
    ------
    ForceError
        NaN/inf signals, a zero or non-unit normal, a malformed velocity, a non-Cantilever.

    Examples
    --------
    >>> lever = Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27)
    >>> n = np.array([0.0, 0.0, 1.0]); v = np.array([0.0, 1e-6, 0.0])
    >>> est = decouple(*lever.angles([0.0, -3e-9, 10e-9]), n, v, lever)
    >>> est.method, np.allclose(est.force, [0.0, -3e-9, 10e-9], rtol=1e-12, atol=1e-21)
    ('contact_normal', True)
    """
    b = _finite_scalar("bending", bending)
    t = _finite_scalar("torsion", torsion)
    nx, ny, nz = _check_normal(normal)
    vx, vy = _check_velocity(velocity)
    params = _parameters(cantilever, min_speed, min_normal_z, max_condition, None)
    out = np.empty(DECOUPLING_OUT.size)
    status = decouple_kernel(b, t, nx, ny, nz, vx, vy, params, out)
    return _estimate(out, status, motion=False)


def decouple_by_motion(
    bending: float,
    torsion: float,
    velocity,
    cantilever: Cantilever,
    *,
    coupling: float | None = None,
    min_speed: float = DEFAULT_MIN_SPEED,
    max_condition: float = DEFAULT_MAX_CONDITION,
) -> ForceEstimate:
    """3D tip force from the motion direction instead of the surface normal ([MWCNT] and [Alabdulmuhsin]).

    The in-plane force is assumed antiparallel to the horizontal motion at angle phi to the beam
    axis x, so

    .. math::

        F_y = \\frac{\\Delta\\theta}{c}, \\qquad F_x = \\frac{F_y}{\\tan\\varphi} = F_y \\frac{v_x}{v_y},
        \\qquad F_z = \\frac{\\Delta\\alpha}{g} - \\kappa F_x .

    Sign conventions and the seeds: [MWCNT] names the lateral axis x and the beam axis y, so its
    Eq. 1 (F_x (h_t + b/2) = k_ct theta_x) is our torsion row with lever arm a = h_t + b/2 = this
    cantilever's ``lever_arm``; its Eq. 3 "F_y = F_x c tan alpha" reads F_y = F_x cot(alpha)
    (alpha measured from its y = our x), i.e. our F_y = F_x tan(phi); friction is antiparallel
    to v, so F_x and F_y share the sign factor :math:`-|f|` and no extra minus appears ([Alabdulmuhsin] Eq. 18's
    minus contradicts its own Eq. 16 and is not used). Its Eq. 6, F_z = k k_v S_v - F_y(h_t+b/2)/l_c,
    has our beta = k delta for k k_v S_v but coupling a/l, from a moment balance on the end
    deflection; the optical lever measures the end slope, whose coupling is 2a/l (docs/design.rst, "Force from the two
    angles"), used here by default. Pass ``coupling=cantilever.lever_arm / cantilever.length`` to
    reproduce [MWCNT] literally.

    This is the contact-normal system with a flat normal n = e_z, so the same kernel, flags and
    fallback apply: motion along the beam axis (v_y -> 0, tan(phi) -> 0, [Alabdulmuhsin]'s
    "unmeasurable" case) is SINGULAR/ILL_CONDITIONED and v = 0 is NO_MOTION; both fall back to
    ``"bending_only"``, F = (0, tau, beta).

    Parameters
    ----------
    bending, torsion : float, radians
    velocity : (2,) or (3,) float, m/s
        Tip velocity (or any vector along the motion direction).
    cantilever : Cantilever
    coupling : float, optional
        kappa override (default 2a/l).
    min_speed, max_condition : float
        As in :func:`decouple`.

    Returns
    -------
    ForceEstimate with method ``"motion_direction"`` or ``"bending_only"``.

    Examples
    --------
    >>> lever = Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27)
    >>> est = decouple_by_motion(*lever.angles([-1e-9, -1e-9, 20e-9]), [1e-6, 1e-6], lever)
    >>> est.method, np.allclose(est.force, [-1e-9, -1e-9, 20e-9], rtol=1e-12, atol=1e-21)
    ('motion_direction', True)
    """
    b = _finite_scalar("bending", bending)
    t = _finite_scalar("torsion", torsion)
    vx, vy = _check_velocity(velocity)
    params = _parameters(cantilever, min_speed, 0.0, max_condition, coupling)
    out = np.empty(DECOUPLING_OUT.size)
    status = decouple_kernel(b, t, 0.0, 0.0, 1.0, vx, vy, params, out)
    return _estimate(out, status, motion=True)


def decouple_many(
    bending,
    torsion,
    normals,
    velocities,
    cantilever: Cantilever,
    *,
    min_speed: float = DEFAULT_MIN_SPEED,
    min_normal_z: float = DEFAULT_MIN_NORMAL_Z,
    max_condition: float = DEFAULT_MAX_CONDITION,
):
    """Vectorised :func:`decouple` for recorded sessions (one validation, one kernel loop).

    Parameters
    ----------
    bending, torsion : (n,) float, radians
    normals : (n, 3) float, unit vectors
    velocities : (n, 2) or (n, 3) float, m/s

    Returns
    -------
    forces : (n, 3) float, newtons
    status : (n,) int64, :class:`DecouplingFlag` bits per sample
    condition : (n,) float
    """
    b = np.ascontiguousarray(bending, dtype=np.float64)
    t = np.ascontiguousarray(torsion, dtype=np.float64)
    n = np.ascontiguousarray(normals, dtype=np.float64)
    v = np.ascontiguousarray(velocities, dtype=np.float64)
    if b.ndim != 1 or t.shape != b.shape:
        raise ForceError(f"bending and torsion must be 1-D arrays of one length (got {b.shape} and {t.shape})")
    if n.shape != (b.size, 3):
        raise ForceError(f"normals must have shape ({b.size}, 3) (got {n.shape})")
    if v.ndim != 2 or v.shape[0] != b.size or v.shape[1] not in (2, 3):
        raise ForceError(f"velocities must have shape ({b.size}, 2) or ({b.size}, 3) (got {v.shape})")
    bad = ~(np.isfinite(b) & np.isfinite(t))
    if bad.any():
        raise ForceError(
            f"bending/torsion contain {int(bad.sum())} NaN or infinite samples (first at index "
            f"{int(np.argmax(bad))}); drop or interpolate them before decoupling"
        )
    if not (np.all(np.isfinite(n)) and np.all(np.isfinite(v))):
        raise ForceError("normals and velocities must be finite")
    norms = np.linalg.norm(n, axis=1)
    off = np.abs(norms - 1.0) > UNIT_TOLERANCE
    if off.any():
        i = int(np.argmax(off))
        raise ForceError(
            f"normals must be unit vectors (row {i} has |n| = {norms[i]:.9g}); "
            "pass normals / np.linalg.norm(normals, axis=1)[:, None]"
        )
    params = decoupling_parameters(cantilever, min_speed, min_normal_z, max_condition)
    forces = np.empty((b.size, 3))
    condition = np.empty(b.size)
    status = np.empty(b.size, dtype=np.int64)
    decouple_many_kernel(b, t, n, v, params, forces, condition, status)
    return forces, status, condition
