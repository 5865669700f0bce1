"""Sphere-on-flat contact models with one interface: Hertz, DMT and JKR.

A rigid-or-elastic sphere of radius ``R`` (the AFM tip) indents an elastic half-space (the
sample) by ``depth`` :math:`\\delta` (docs/design.rst, "Units and conventions": :math:`\\delta = R - ` signed distance
of the tip centre, positive when the sphere penetrates). Each model answers the same questions:

* ``contact_radius(depth=...)`` / ``contact_radius(load=...)`` - radius *a* of the contact disk,
* ``load(depth)`` - normal load *P* (positive compressive, negative tensile),
* ``depth(load)`` - indentation under load control,
* ``pull_off_force()`` - the most tensile load the contact sustains under load control,
* ``jump_out_depth()`` / ``jump_in_depth()`` - where the contact breaks while retracting and
  forms while approaching under displacement control (the hysteresis of adhesive contacts),
* ``contact_state(...)`` - a :class:`ContactState` record with the flags (in contact, stable,
  branch) for the cases where a plain number would hide something.

``effective_modulus`` is always the plane-strain contact modulus :math:`E^*`,

.. math:: \\frac{1}{E^*} = \\frac{1-\\nu_1^2}{E_1} + \\frac{1-\\nu_2^2}{E_2},

not :math:`K = 4E^*/3`, the other convention found in the JKR/Maugis literature (Maugis 1992,
Johnson & Greenwood 1997 write their equations with *K*). :func:`arsurf.effective_modulus`
combines tip and sample materials.

Beyond pull-off or jump-out the models return a clear *no contact* result (radius 0, load 0,
``in_contact=False`` in the record) rather than NaN. ``depth(load)`` for a load below the pull-off
force has no equilibrium at all and raises :class:`~arsurf.errors.ContactError`.

The Maugis-Dugdale model, which contains all three as limits, lives in
:mod:`arsurf.contact.maugis_dugdale` and shares this interface.

Sources: H. Hertz (1882); B. V. Derjaguin, V. M. Muller, Yu. P. Toporov, J. Colloid Interface
Sci. 53, 314 (1975) (DMT); K. L. Johnson, K. Kendall, A. D. Roberts, Proc. R. Soc. A 324, 301
(1971) (JKR); K. L. Johnson, *Contact Mechanics* (Cambridge 1985) ch. 4; D. Maugis, J. Colloid
Interface Sci. 150, 243 (1992).

Examples
--------
>>> from arsurf.contact.mechanics import Hertz, JKR
>>> h = Hertz(tip_radius=20e-9, effective_modulus=50e9)
>>> round(h.contact_radius(depth=1e-9) * 1e9, 6)   # a = sqrt(R d)
4.472136
>>> j = JKR(tip_radius=20e-9, effective_modulus=50e9, work_of_adhesion=0.1)
>>> round(j.pull_off_force() / (3.14159265358979 * 0.1 * 20e-9), 6)
-1.5
"""
from __future__ import annotations

import abc
import math
from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from numba import njit

from arsurf import _validation, status
from arsurf.errors import ContactError

__all__ = [
    "Branch",
    "ContactModel",
    "ContactState",
    "DMT",
    "Hertz",
    "JKR",
    "jkr_radius_from_depth_kernel",
    "SMALL_CONTACT_LIMIT",
    "parabolic_gap_error",
]

#: Largest contact radius per tip radius, a/R, for which the sphere-on-flat models hold. Hertz, DMT,
#: JKR and Maugis-Dugdale all replace the sphere by the paraboloid r²/2R, an approximation for
#: a << R (Johnson 1985, §4.2). The relative error of that gap at the contact's edge is
#: :func:`parabolic_gap_error`: 4.2 % at a/R = 0.4, 6.7 % at 0.5, 20 % at 0.8, and the
#: half-space's small-strain elasticity is strained as far. Beyond 0.4 (a Hertz depth of 0.16 R)
#: a result is flagged :data:`arsurf.status.BEYOND_MODEL`: the contact law is extrapolated there,
#: not applied.
SMALL_CONTACT_LIMIT = 0.4


def parabolic_gap_error(a_over_r: float) -> float:
    r"""Relative error of the paraboloid gap r²/2R against the sphere's R - sqrt(R² - r²) at r = a.

    .. math:: \epsilon(x) = 1 - \frac{x^2 / 2}{1 - \sqrt{1 - x^2}}, \quad x = a/R

    >>> round(parabolic_gap_error(SMALL_CONTACT_LIMIT), 3)
    0.042
    """
    x = float(a_over_r)
    if not 0.0 < x <= 1.0:
        raise ContactError(f"a/R must be in (0, 1] (got {a_over_r!r}): a contact disk wider than the sphere has no gap")
    return 1.0 - 0.5 * x * x / (1.0 - math.sqrt(1.0 - x * x))


class Branch(IntEnum):
    """Which part of the equilibrium curve a state lies on: the kernels' status codes >= 0, whose
    table is :mod:`arsurf.status`.

    ``CONTACT``: the surfaces touch over a disk of radius a >= 0.
    ``COHESIVE``: no contact (a = 0) but an adhesive (Dugdale) zone still pulls the surfaces
    together and carries a tensile load (Maugis-Dugdale only).
    ``SEPARATED``: no interaction: radius 0, load 0.
    """

    CONTACT = status.CONTACT
    COHESIVE = status.COHESIVE
    SEPARATED = status.SEPARATED


_BRANCH_NAMES = np.array(status.BRANCH_NAMES)


@dataclass(frozen=True)
class ContactState:
    """One equilibrium of a sphere-on-flat contact.

    Scalars for a scalar query; arrays of the query's shape for an array query.

    Attributes
    ----------
    radius : float, metres
        Contact radius *a* (0 when not in contact).
    load : float, newtons
        Normal load carried by the interface (positive compressive; negative is adhesive
        tension; 0 when separated).
    depth : float, metres
        Indentation depth; ``-inf`` for the separated state under load control (the tip has
        pulled off and there is no finite equilibrium depth).
    in_contact : bool
        True when the surfaces touch (a > 0, or a = 0 exactly at the DMT/Hertz contact point).
    stable : bool
        Stable under the control mode of the query (displacement for ``depth=``, load for
        ``load=``). The default queries return stable states only; :meth:`ContactModel.equilibria`
        also lists unstable ones with ``stable=False``.
    branch : str
        ``"contact"``, ``"cohesive"`` or ``"separated"`` (see :class:`Branch`).
    """

    radius: float | np.ndarray
    load: float | np.ndarray
    depth: float | np.ndarray
    in_contact: bool | np.ndarray
    stable: bool | np.ndarray
    branch: str | np.ndarray


# ---------------------------------------------------------------------------------------------
# validation helpers (shared with maugis_dugdale.py)
# ---------------------------------------------------------------------------------------------

def _positive(value, name: str, unit: str, meaning: str) -> float:
    return _validation.positive(value, name, ContactError, unit=unit, hint=f"it is {meaning}")


def _non_negative(value, name: str, unit: str, meaning: str) -> float:
    return _validation.non_negative(value, name, ContactError, unit=unit, hint=f"it is {meaning}")


def _finite_array(value, name: str, meaning: str) -> tuple[np.ndarray, bool]:
    """Coerce a query to a float64 array; returns (array, was_scalar). NaN/inf -> ContactError."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ContactError(f"`{name}` must be a number or an array of numbers (got {value!r}); {meaning}") from None
    if not np.all(np.isfinite(arr)):
        bad = float(arr[~np.isfinite(arr)].ravel()[0])
        idx = "" if arr.ndim == 0 else f" at index {np.argwhere(~np.isfinite(arr))[0].tolist()}"
        raise ContactError(
            f"`{name}` must be finite (got {bad!r}{idx}); {meaning}; "
            "drop or fill the invalid samples before asking the contact model"
        )
    return arr, arr.ndim == 0


def _out(arr: np.ndarray, scalar: bool):
    return float(arr) if scalar else arr


# ---------------------------------------------------------------------------------------------
# the common interface
# ---------------------------------------------------------------------------------------------

class ContactModel(abc.ABC):
    """Common interface of the sphere-on-flat contact models (Hertz, DMT, JKR, Maugis-Dugdale).

    Subclasses implement two vectorised hooks on validated float64 arrays,
    :meth:`_solve_depth` (displacement control, the branch connected to contact) and
    :meth:`_solve_load` (load control, stable branch), plus the critical points. Everything
    else - validation, scalar/array handling, approach hysteresis, records - lives here.

    Parameters
    ----------
    tip_radius : float, metres
        Radius *R* of the spherical tip (positive).
    effective_modulus : float, pascals
        Contact modulus :math:`E^*` with :math:`1/E^* = (1-\\nu_1^2)/E_1 + (1-\\nu_2^2)/E_2`
        (not :math:`K = 4E^*/3`).
    work_of_adhesion : float, J/m^2
        Dupré work of adhesion *w* (>= 0); see :func:`arsurf.contact.materials.work_of_adhesion`.
    """

    #: short model name used in messages and records
    name = "contact model"

    def __init__(self, tip_radius: float, effective_modulus: float, work_of_adhesion: float = 0.0):
        self._R = _positive(tip_radius, "tip_radius", "m", "the radius of the spherical tip in metres")
        self._E = _positive(
            effective_modulus, "effective_modulus", "Pa",
            "the contact modulus E* (1/E* = (1-nu1^2)/E1 + (1-nu2^2)/E2) in pascals; "
            "arsurf.effective_modulus(tip, sample) computes it",
        )
        self._w = _non_negative(
            work_of_adhesion, "work_of_adhesion", "J/m^2",
            "the Dupre work of adhesion in J/m^2 (0 for no adhesion)",
        )

    # -- parameters -----------------------------------------------------------------------
    @property
    def tip_radius(self) -> float:
        """Tip radius *R* in metres."""
        return self._R

    @property
    def effective_modulus(self) -> float:
        """Contact modulus :math:`E^*` in pascals."""
        return self._E

    @property
    def work_of_adhesion(self) -> float:
        """Work of adhesion *w* in J/m^2."""
        return self._w

    @property
    def K(self) -> float:
        """The literature's :math:`K = 4E^*/3` in pascals (Maugis 1992, Johnson-Greenwood 1997)."""
        return 4.0 * self._E / 3.0

    def __repr__(self) -> str:
        return (f"{type(self).__name__}(tip_radius={self._R!r}, effective_modulus={self._E!r}, "
                f"work_of_adhesion={self._w!r})")

    # -- hooks ----------------------------------------------------------------------------
    @abc.abstractmethod
    def _solve_depth(self, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(radius, load, branch code) on the branch connected to contact (retracting)."""

    @abc.abstractmethod
    def _solve_load(self, load: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(radius, depth) on the load-control stable branch; only called for load >= pull-off."""

    @abc.abstractmethod
    def pull_off_force(self) -> float:
        """Most tensile load (N, <= 0) the contact sustains under load control."""

    @abc.abstractmethod
    def jump_out_depth(self) -> float:
        """Depth (m) below which a retracting tip loses the contact under displacement control."""

    @abc.abstractmethod
    def jump_in_depth(self) -> float:
        """Depth (m) at which an approaching tip snaps into contact under displacement control."""

    # -- public API -----------------------------------------------------------------------
    def _depth_query(self, depth, approach: bool):
        d, scalar = _finite_array(depth, "depth", "depth is the indentation in metres (R - signed distance of the tip centre)")
        radius, load, code = self._solve_depth(np.atleast_1d(d).ravel())
        if approach:
            # coming from far away: no adhesive neck exists before the jump-in depth
            out = np.atleast_1d(d).ravel() < self.jump_in_depth()
            radius = np.where(out, 0.0, radius)
            load = np.where(out, 0.0, load)
            code = np.where(out, int(Branch.SEPARATED), code)
        shape = d.shape
        return radius.reshape(shape), load.reshape(shape), code.reshape(shape), d, scalar

    def _load_query(self, load, *, strict: bool):
        p, scalar = _finite_array(load, "load", "load is the normal force in newtons (negative = tensile)")
        flat = np.atleast_1d(p).ravel()
        p_c = self.pull_off_force()
        below = flat < p_c
        if strict and below.any():
            worst = float(flat[below].min())
            raise ContactError(
                f"{self.name}: no equilibrium for load {worst!r} N, below the pull-off force "
                f"{p_c!r} N (the tip separates under load control); ask only loads >= pull_off_force(), "
                "or use contact_state(load=...) which flags the separated state"
            )
        radius = np.zeros_like(flat)
        depth = np.full_like(flat, -np.inf)
        ok = ~below
        if ok.any():
            r_ok, d_ok = self._solve_load(flat[ok])
            radius[ok] = r_ok
            depth[ok] = d_ok
        return radius.reshape(p.shape), depth.reshape(p.shape), below.reshape(p.shape), p, scalar

    def contact_radius(self, depth=None, *, load=None, approach: bool = False):
        """Contact radius *a* (m) for a given depth (displacement control) or load (load control).

        Parameters
        ----------
        depth : float or array, metres, optional
            Indentation depth (negative = gap). Exactly one of ``depth`` and ``load``.
        load : float or array, newtons, optional
            Normal load (negative = tensile).
        approach : bool
            Depth control only: True when the tip comes from out of contact (no adhesive neck
            yet), False (default) when it is in contact or retracting from contact. Adhesive
            models differ between the two for depths between jump-out and jump-in.

        Returns
        -------
        float or array, metres
            Contact radius on the stable branch; 0 where there is no contact (beyond jump-out
            or pull-off).
        """
        if (depth is None) == (load is None):
            raise ContactError("contact_radius needs exactly one of depth=... (m) or load=... (N)")
        if depth is not None:
            radius, _, _, _, scalar = self._depth_query(depth, approach)
            return _out(radius, scalar)
        radius, _, _, _, scalar = self._load_query(load, strict=False)
        return _out(radius, scalar)

    def load(self, depth, *, approach: bool = False):
        """Normal load *P* (N) at a given depth under displacement control (stable branch).

        Returns 0 where the surfaces do not interact (beyond jump-out, or before jump-in when
        ``approach=True``). See :meth:`contact_radius` for the parameters.
        """
        _, load, _, _, scalar = self._depth_query(depth, approach)
        return _out(load, scalar)

    def depth(self, load):
        """Indentation depth (m) under load control, on the load-control stable branch.

        Raises
        ------
        ContactError
            For loads below :meth:`pull_off_force`: there is no equilibrium, the tip separates.
        """
        _, depth, _, _, scalar = self._load_query(load, strict=True)
        return _out(depth, scalar)

    def contact_state(self, depth=None, *, load=None, approach: bool = False) -> ContactState:
        """The full stable equilibrium as a :class:`ContactState` record (flags included).

        Exactly one of ``depth`` (displacement control) or ``load`` (load control); see
        :meth:`contact_radius`. Under load control below the pull-off force the record is the
        separated state (radius 0, load 0, depth -inf, ``in_contact=False``).
        """
        if (depth is None) == (load is None):
            raise ContactError("contact_state needs exactly one of depth=... (m) or load=... (N)")
        if depth is not None:
            radius, ld, code, d, scalar = self._depth_query(depth, approach)
            in_contact = code == int(Branch.CONTACT)
            return self._record(radius, ld, d, in_contact, np.ones_like(in_contact), code, scalar)
        radius, dep, below, p, scalar = self._load_query(load, strict=False)
        code = np.where(below, int(Branch.SEPARATED), int(Branch.CONTACT))
        ld = np.where(below, 0.0, p)
        return self._record(radius, ld, dep, ~below, np.ones_like(below), code, scalar)

    def equilibria(self, depth=None, *, load=None) -> list[ContactState]:
        """Every equilibrium at one scalar depth or load, stable and unstable, by radius.

        Hertz and DMT have a single equilibrium; adhesive models override this to list the
        unstable branch too (``stable=False``).
        """
        st = self.contact_state(depth=depth, load=load)
        if np.ndim(st.radius) != 0:
            raise ContactError("equilibria() takes one scalar depth or load (got an array)")
        return [st]

    def _record(self, radius, load, depth, in_contact, stable, code, scalar) -> ContactState:
        names = _BRANCH_NAMES[np.asarray(code, dtype=np.int64)]
        if scalar:
            return ContactState(float(radius), float(load), float(depth), bool(in_contact),
                                bool(stable), str(names))
        return ContactState(np.asarray(radius, float), np.asarray(load, float), np.asarray(depth, float),
                            np.asarray(in_contact, bool), np.asarray(stable, bool), names)

    @classmethod
    def from_materials(cls, tip_radius: float, tip, sample, **kwargs):
        """Build the model from two :class:`~arsurf.contact.materials.Material` records.

        ``effective_modulus`` and ``work_of_adhesion`` are combined with
        :func:`~arsurf.contact.materials.effective_modulus` and
        :func:`~arsurf.contact.materials.work_of_adhesion`; extra keyword arguments (e.g.
        ``dugdale_stress`` for Maugis-Dugdale, or an explicit ``work_of_adhesion``) are passed on.
        """
        from arsurf.contact.materials import effective_modulus, work_of_adhesion

        kwargs.setdefault("work_of_adhesion", work_of_adhesion(tip, sample))
        if cls is Hertz:
            kwargs.pop("work_of_adhesion")
        return cls(tip_radius, effective_modulus(tip, sample), **kwargs)


# ---------------------------------------------------------------------------------------------
# Hertz
# ---------------------------------------------------------------------------------------------

class Hertz(ContactModel):
    """Hertz contact of a sphere on a flat, no adhesion.

    .. math:: a^2 = R\\delta, \\qquad P = \\tfrac{4}{3} E^* R^{1/2} \\delta^{3/2} = \\frac{4E^* a^3}{3R}

    For :math:`\\delta \\le 0` there is no contact (radius 0, load 0); a tensile load has no
    equilibrium (pull-off force 0).

    Parameters
    ----------
    tip_radius : float, metres
    effective_modulus : float, pascals
        :math:`E^*`, with :math:`1/E^* = (1-\\nu_1^2)/E_1 + (1-\\nu_2^2)/E_2` (not K = 4E*/3).

    Source: Johnson, *Contact Mechanics* (1985), Eq. 4.22-4.23.

    Examples
    --------
    >>> h = Hertz(10e-9, 100e9)
    >>> round(h.load(1e-9) * 1e9, 3)   # nN
    421.637
    """

    name = "Hertz"

    def __init__(self, tip_radius: float, effective_modulus: float):
        super().__init__(tip_radius, effective_modulus, 0.0)

    def __repr__(self) -> str:
        return f"Hertz(tip_radius={self._R!r}, effective_modulus={self._E!r})"

    def _solve_depth(self, depth):
        d = np.maximum(depth, 0.0)
        radius = np.sqrt(self._R * d)
        load = 4.0 / 3.0 * self._E * np.sqrt(self._R) * d ** 1.5
        code = np.where(depth > 0.0, int(Branch.CONTACT), int(Branch.SEPARATED))
        return radius, load, code

    def _solve_load(self, load):
        radius = np.cbrt(3.0 * load * self._R / (4.0 * self._E))
        return radius, radius * radius / self._R

    def pull_off_force(self) -> float:
        return 0.0

    def jump_out_depth(self) -> float:
        return 0.0

    def jump_in_depth(self) -> float:
        return 0.0


# ---------------------------------------------------------------------------------------------
# DMT
# ---------------------------------------------------------------------------------------------

class DMT(ContactModel):
    """Derjaguin-Muller-Toporov contact: Hertz deformation plus a constant adhesive force.

    .. math:: a^2 = R\\delta, \\qquad P = \\frac{4E^* a^3}{3R} - 2\\pi w R \\quad (\\delta \\ge 0)

    Pull-off under load control at *a* = 0 with :math:`P_c = -2\\pi w R`; under displacement
    control the contact breaks at :math:`\\delta = 0` (jump-out = jump-in = 0). The DMT model
    has no interaction law for a gap: for :math:`\\delta < 0` it returns the separated state
    (use :class:`~arsurf.contact.maugis_dugdale.MaugisDugdale` for a finite-range adhesive tail).
    It is the :math:`\\lambda \\to 0` limit of Maugis-Dugdale.

    Parameters
    ----------
    tip_radius : float, metres
    effective_modulus : float, pascals
        :math:`E^*` (not K = 4E*/3).
    work_of_adhesion : float, J/m^2

    Source: Derjaguin, Muller & Toporov, J. Colloid Interface Sci. 53, 314 (1975); Maugis (1992).

    Examples
    --------
    >>> m = DMT(20e-9, 50e9, 0.05)
    >>> round(m.pull_off_force() * 1e9, 4)    # -2 pi w R in nN
    -6.2832
    """

    name = "DMT"

    def _solve_depth(self, depth):
        d = np.maximum(depth, 0.0)
        radius = np.sqrt(self._R * d)
        load = 4.0 * self._E * radius ** 3 / (3.0 * self._R) - 2.0 * math.pi * self._w * self._R
        touching = depth >= 0.0
        load = np.where(touching, load, 0.0)
        code = np.where(touching, int(Branch.CONTACT), int(Branch.SEPARATED))
        return radius, load, code

    def _solve_load(self, load):
        radius = np.cbrt(3.0 * self._R * np.maximum(load - self.pull_off_force(), 0.0) / (4.0 * self._E))
        return radius, radius * radius / self._R

    def pull_off_force(self) -> float:
        return -2.0 * math.pi * self._w * self._R

    def jump_out_depth(self) -> float:
        return 0.0

    def jump_in_depth(self) -> float:
        return 0.0


# ---------------------------------------------------------------------------------------------
# JKR
# ---------------------------------------------------------------------------------------------

_JKR_K = 2.0 * math.sqrt(6.0) / 3.0          # Delta = A^2 - K sqrt(A)
_JKR_Y_FOLD = (_JKR_K / 4.0) ** (1.0 / 3.0)   # sqrt(A) at the displacement-control fold, A = 6^(-1/3)
_JKR_D_FOLD = _JKR_Y_FOLD ** 4 - _JKR_K * _JKR_Y_FOLD   # = -3 * 6^(-2/3)


@njit(cache=True)
def jkr_radius_from_depth_kernel(delta_bar):
    """Non-dimensional JKR contact radius A on the stable branch for a depth Delta-bar.

    Solves :math:`\\bar\\Delta = A^2 - \\tfrac{2}{3}\\sqrt{6A}` for the root with
    :math:`A \\ge 6^{-1/3}` (the branch stable under displacement control), by a safeguarded
    Newton iteration on :math:`y = \\sqrt{A}` for :math:`\\sqrt{y^4 - ky - \\bar\\Delta_c} = \\sqrt{\\bar\\Delta - \\bar\\Delta_c}`
    (the square root makes the fold at :math:`\\bar\\Delta_c = -3\\cdot 6^{-2/3}` a simple root).

    Returns
    -------
    (status, A) : (int, float)
        status (:mod:`arsurf.status`) CONTACT, SEPARATED (below the jump-out depth, A = 0),
        NON_FINITE (NaN input) or NOT_CONVERGED (never observed; reported, not hidden).
    """
    if not math.isfinite(delta_bar):
        return status.NON_FINITE, 0.0
    if delta_bar < _JKR_D_FOLD:
        return status.SEPARATED, 0.0
    r = math.sqrt(delta_bar - _JKR_D_FOLD)
    y_lo = _JKR_Y_FOLD
    # two upper bounds: the fold parabola (F'' >= 12 y_fold^2) and y^4 >= 2|Delta| with y^3 >= 2k
    y_hi = min(y_lo + r / (math.sqrt(6.0) * y_lo),
               max((2.0 * abs(delta_bar)) ** 0.25, (2.0 * _JKR_K) ** (1.0 / 3.0)))
    y_hi = max(y_hi, y_lo)
    y = y_hi
    for _ in range(100):
        f = y ** 4 - _JKR_K * y - _JKR_D_FOLD
        if f <= 0.0:
            y_lo = y
            y = 0.5 * (y_lo + y_hi)
            continue
        g = math.sqrt(f) - r
        if g > 0.0:
            y_hi = y
        else:
            y_lo = y
        dg = (4.0 * y ** 3 - _JKR_K) / (2.0 * math.sqrt(f))
        newton = dg > 0.0
        yn = y - g / dg if newton else 0.5 * (y_lo + y_hi)
        if not (y_lo <= yn <= y_hi):
            yn = 0.5 * (y_lo + y_hi)
            newton = False
        if g == 0.0 or y_hi - y_lo <= 4e-16 * y:
            return status.CONTACT, yn * yn
        if newton:
            # rounding noise of g next to the fold limits the attainable step
            noise = 4.4e-16 * (y ** 4 + _JKR_K * y - _JKR_D_FOLD) / (2.0 * math.sqrt(f) * dg)
            if abs(yn - y) <= max(1e-9 * y, 4.0 * noise):
                return status.CONTACT, yn * yn
        y = yn
    return status.NOT_CONVERGED, y * y


@njit(cache=True)
def _jkr_depth_many(delta_bar, out_a, out_status):
    for i in range(delta_bar.size):
        st, a = jkr_radius_from_depth_kernel(delta_bar[i])
        out_a[i] = a
        out_status[i] = st


class JKR(ContactModel):
    """Johnson-Kendall-Roberts adhesive contact (short-range adhesion, compliant solids).

    With :math:`K = 4E^*/3` and the Maugis units :math:`A = a (K/\\pi w R^2)^{1/3}`,
    :math:`\\bar P = P/\\pi w R`, :math:`\\bar\\Delta = \\delta (K^2/\\pi^2 w^2 R)^{1/3}`:

    .. math::
        \\bar P = A^3 - \\sqrt{6A^3}, \\qquad \\bar\\Delta = A^2 - \\tfrac{2}{3}\\sqrt{6A}

    i.e. :math:`P = 4E^*a^3/3R - \\sqrt{8\\pi w E^* a^3}` and
    :math:`\\delta = a^2/R - \\sqrt{2\\pi w a / E^*}`. Critical points: pull-off under load control
    :math:`\\bar P_c = -3/2` at :math:`A = (3/2)^{1/3}`; under displacement control the contact
    breaks at the fold :math:`\\bar\\Delta = -3\\cdot 6^{-2/3}` (:math:`\\delta = -\\tfrac34 (\\pi^2 w^2 R/E^{*2})^{1/3}`,
    load :math:`-5/6\\,\\pi w R`, :math:`A = 6^{-1/3}`) and forms at :math:`\\delta = 0`
    (jumping to :math:`A = (8/3)^{1/3}`). The returned branch is the one stable under the
    control mode; :meth:`equilibria` lists the unstable small-radius branch too.

    Parameters
    ----------
    tip_radius : float, metres
    effective_modulus : float, pascals
        :math:`E^*` (not K = 4E*/3).
    work_of_adhesion : float, J/m^2
        0 gives Hertz.

    Source: Johnson, Kendall & Roberts, Proc. R. Soc. A 324, 301 (1971); Maugis (1992) for the
    non-dimensional form; Johnson, *Contact Mechanics* §5.5.

    Examples
    --------
    >>> j = JKR(20e-9, 50e9, 0.1)
    >>> a0 = j.contact_radius(load=0.0)   # zero-load radius (9 pi w R^2 / 2E*)^(1/3)
    >>> round(a0 * 1e9, 4)
    2.2447
    """

    name = "JKR"

    def __init__(self, tip_radius: float, effective_modulus: float, work_of_adhesion: float):
        super().__init__(tip_radius, effective_modulus, work_of_adhesion)
        if self._w > 0.0:
            K = self.K
            self.radius_scale = (math.pi * self._w * self._R ** 2 / K) ** (1.0 / 3.0)
            self.depth_scale = self.radius_scale ** 2 / self._R
            self.load_scale = math.pi * self._w * self._R

    def _solve_depth(self, depth):
        if self._w == 0.0:
            return Hertz(self._R, self._E)._solve_depth(depth)
        A = np.empty_like(depth)
        status = np.empty(depth.shape, np.int64)
        _jkr_depth_many(depth / self.depth_scale, A, status)
        if (status < 0).any():
            i = int(np.argmax(status < 0))
            raise ContactError(f"JKR solver failed (status {int(status[i])}) for depth {float(depth[i])!r} m; "
                               "this is a bug, please report it with this number")
        P = A ** 3 - np.sqrt(6.0 * A ** 3)
        contact = status == Branch.CONTACT
        return A * self.radius_scale, np.where(contact, P * self.load_scale, 0.0), status

    def _solve_load(self, load):
        if self._w == 0.0:
            return Hertz(self._R, self._E)._solve_load(load)
        p = load / self.load_scale
        z = 0.5 * (math.sqrt(6.0) + np.sqrt(np.maximum(6.0 + 4.0 * p, 0.0)))   # z = A^(3/2)
        A = np.cbrt(z * z)
        delta = A * A - _JKR_K * np.sqrt(A)
        return A * self.radius_scale, delta * self.depth_scale

    def pull_off_force(self) -> float:
        return -1.5 * math.pi * self._w * self._R

    def jump_out_depth(self) -> float:
        return _JKR_D_FOLD * self.depth_scale if self._w > 0.0 else 0.0

    def jump_in_depth(self) -> float:
        return 0.0

    def equilibria(self, depth=None, *, load=None) -> list[ContactState]:
        """All equilibria at one scalar depth or load (stable and unstable), by decreasing radius.

        Displacement control: for :math:`\\bar\\Delta_c < \\bar\\Delta < 0` there is the stable
        large-radius state, the unstable small-radius state (``stable=False``) and the separated
        state (stable too: JKR has no interaction without contact). Load control: for
        :math:`-3/2 < \\bar P < 0` a stable and an unstable contact.
        """
        from scipy.optimize import brentq

        stable = self.contact_state(depth=depth, load=load)
        if np.ndim(stable.radius) != 0:
            raise ContactError("equilibria() takes one scalar depth or load (got an array)")
        if self._w == 0.0:
            return [stable]
        out = [stable] if stable.branch == "contact" else []
        y_fold = _JKR_Y_FOLD
        if depth is not None:
            db = float(depth) / self.depth_scale
            if _JKR_D_FOLD < db < 0.0:
                y = brentq(lambda y: y ** 4 - _JKR_K * y - db, 0.0, y_fold, xtol=1e-15)
                A = y * y
                out.append(ContactState(A * self.radius_scale, (A ** 3 - math.sqrt(6 * A ** 3)) * self.load_scale,
                                        float(depth), True, False, "contact"))
            if db < 0.0:
                out.append(ContactState(0.0, 0.0, float(depth), False, True, "separated"))
        else:
            pb = float(load) / self.load_scale
            if -1.5 < pb < 0.0:
                z = 0.5 * (math.sqrt(6.0) - math.sqrt(6.0 + 4.0 * pb))
                A = z ** (2.0 / 3.0)
                out.append(ContactState(A * self.radius_scale, float(load),
                                        (A * A - _JKR_K * math.sqrt(A)) * self.depth_scale, True, False, "contact"))
            if not out:
                out.append(stable)
        return out
