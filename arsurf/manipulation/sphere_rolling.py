r"""Rolling a microsphere under a tipless cantilever, with forces for two haptic axes ([Bolopion]).

A sphere squeezed between the substrate and a tipless cantilever rolls without sliding when the
cantilever moves ([Bolopion], Sec. III). Its centre then moves by half the cantilever's motion in
the substrate frame ([Bolopion] Eq. 12):

.. math:: x_s(j) = x_s(0) + \frac{x_c(j) - x_c(0)}{2} .

Eq. 12 is written for the sphere's position; the stiffness of Eq. 13 needs the *load point on the
beam*, measured from the clamp, ``x_p = x_s - x_c``. In the beam frame the same kinematics read
``x_p(j) = x_p(0) - (x_c(j) - x_c(0))/2``: advancing the cantilever towards its free end brings the
load point towards the clamp. :func:`sphere_position` is Eq. 12 as printed (substrate frame),
:func:`load_point` its beam-frame form; the two agree when both frames coincide at j = 0.

Rendered forces (the deflection at the free end, delta(L, 0), is servoed constant):

.. math::

    F_e^x(x_p) = k_z(x_p)\,\frac{2 x_p}{3L - x_p}\,\delta(L,0) - k_z(L)\,\delta(L,0)
    \qquad \text{(Eq. 13 with Eq. 5-7, minus its value at } x_p = L\text{)}

    F_e^y = \frac{k_{t\phi}(L)}{w/2}\,\phi(L,0) \qquad \text{(Eq. 14)}

With [Bolopion]'s beam, :math:`k_z(x_p) = (L/x_p)^3 k_z(L)` and the first term is Eq. 8,
:math:`2L^3 k_z(L)\delta(L,0) / (x_p^2 (3L - x_p))`: it is smallest at the extremity, so the offset
makes the extremity a zero-force stable equilibrium (Fig. 2a, Sec. III-A). :math:`F_e^y` changes
sign with the twist and grows with it (Fig. 2b). The two are uncoupled, so they drive two haptic
axes (Sec. III-C). On the handle, whose axes are the cantilever's x and y, the forces are
restoring: ``F_m = (-F_e^x, +F_e^y)`` (advancing the cantilever along +x moves the load point
away from the extremity; moving it along +y puts the sphere at negative y_p, a negative twist).

The stiffness at the load point comes from the cantilever model of :mod:`arsurf.force.cantilever`
(:meth:`RollingProbe.from_cantilever`) or from any two callables ``k_z(x_p)``, ``k_t(x_p)``.

Forward model for simulations (what the photodiode would measure): the sphere pushes the beam
with :math:`F_z = k_z(x_p)\,\delta(x_p)`, :math:`\delta(x_p) = \frac{2x_p}{3L-x_p}\delta(L,0)` (Eq. 5, 7);
at a lateral offset y_p it twists the clamped segment ``[0, x_p]`` by
:math:`\phi = F_z y_p / k_{t\phi}(x_p)`, which the untwisted rest of the beam carries to the end:
:math:`\phi(L,0) = \phi(x_p,0)` (Eq. 10 read as a torsion spring).

Examples
--------
>>> E, nu, L, t, w = 150e9, 0.17, 220e-6, 2.9e-6, 27e-6
>>> kz = lambda x: E * w * t**3 / (4 * x**3)
>>> kt = lambda x: E / (2 * (1 + nu)) * w * t**3 / (3 * x)
>>> probe = RollingProbe(L, w, kz, kt)
>>> round(probe.normal_force(L, 0.7e-6) * 1e6, 2)   # [Bolopion]: about 1.7 uN at the extremity
1.62
>>> probe.force_x(L, 0.7e-6)                        # the extremity is the equilibrium
0.0
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from arsurf.errors import ManipulationError


def _finite_array(name: str, value, what: str) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64)
    if not np.all(np.isfinite(a)):
        raise ManipulationError(f"{name} must be finite ({what}) (got {value!r})")
    return a


def _out(a: np.ndarray):
    return float(a) if a.ndim == 0 else a


def sphere_position(x_c, x_c0: float, x_s0: float):
    """Sphere centre in the substrate frame after the cantilever moved from x_c0 to x_c (Eq. 12).

    .. math:: x_s(j) = x_s(0) + \\frac{x_c(j) - x_c(0)}{2}

    Rolling without sliding on both the substrate and the beam: the centre moves half as far as
    the beam. The same holds along y for lateral rolling.

    Parameters
    ----------
    x_c : float or array, metres
        Cantilever positions (nanotranslator readings).
    x_c0, x_s0 : float, metres
        Initial cantilever position and sphere position.

    Examples
    --------
    >>> sphere_position([0.0, 2e-6], 0.0, 5e-6)
    array([5.e-06, 6.e-06])
    """
    xc = _finite_array("x_c", x_c, "metres")
    return _out(float(x_s0) + 0.5 * (xc - float(x_c0)))


def load_point(x_c, x_c0: float, x_p0: float):
    """Load point on the beam (from the clamp) after the cantilever moved from x_c0 to x_c.

    .. math:: x_p(j) = x_p(0) - \\frac{x_c(j) - x_c(0)}{2}

    Eq. 12 in the beam frame: ``x_p = x_s - x_c`` with :func:`sphere_position` for ``x_s``.

    Examples
    --------
    >>> load_point(20e-6, 0.0, 220e-6)     # advance the beam by 20 um: the sphere is 10 um inward
    0.00021
    """
    xc = _finite_array("x_c", x_c, "metres")
    return _out(float(x_p0) - 0.5 * (xc - float(x_c0)))


@dataclass(frozen=True)
class RollingProbe:
    """A tipless cantilever used to roll a sphere: the rendered forces of [Bolopion] Eq. 13-14.

    Parameters
    ----------
    length : float, metres
        Beam length L (clamp to free end; the laser spot E is at the free end).
    width : float, metres
        Beam width w (a sphere with :math:`|y_p| > w/2` has left the beam).
    normal_stiffness : callable x_p -> N/m
        k_z at a load point ([Bolopion] Eq. 6); vectorised over numpy arrays.
    torsional_stiffness : callable x_p -> N m/rad
        k_tphi at a load point ([Bolopion] Eq. 10).

    Examples
    --------
    >>> probe = RollingProbe(200e-6, 30e-6, lambda x: 2.0 * (200e-6 / x) ** 3, lambda x: 6e-8 * 200e-6 / x)
    >>> probe.force_y(0.0)
    0.0
    """

    length: float
    width: float
    normal_stiffness: Callable
    torsional_stiffness: Callable

    def __post_init__(self) -> None:
        for name in ("length", "width"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v > 0.0):
                raise ManipulationError(f"{name} must be positive, in metres (got {getattr(self, name)!r})")
            object.__setattr__(self, name, v)
        for name in ("normal_stiffness", "torsional_stiffness"):
            if not callable(getattr(self, name)):
                raise ManipulationError(
                    f"{name} must be a callable of the load point x_p (metres) (got {getattr(self, name)!r}); "
                    "use RollingProbe.from_cantilever(lever) for arsurf's cantilever model"
                )

    @classmethod
    def from_cantilever(cls, lever) -> "RollingProbe":
        """Build from an :class:`arsurf.force.cantilever.Cantilever` (its ``normal_stiffness_at``
        and ``torsional_stiffness_at`` are [Bolopion] Eq. 6 and Eq. 10)."""
        for attr in ("length", "width", "normal_stiffness_at", "torsional_stiffness_at"):
            if not hasattr(lever, attr):
                raise ManipulationError(
                    f"from_cantilever needs an object with length, width, normal_stiffness_at and "
                    f"torsional_stiffness_at, like arsurf.force.cantilever.Cantilever (missing {attr!r})"
                )
        return cls(lever.length, lever.width, lever.normal_stiffness_at, lever.torsional_stiffness_at)

    # -- checks ----------------------------------------------------------------------------------
    def _x(self, x_p) -> np.ndarray:
        x = _finite_array("x_p", x_p, "metres from the clamp")
        if np.any(x <= 0.0) or np.any(x > self.length * (1.0 + 1e-12)):
            raise ManipulationError(
                f"load point x_p must lie on the beam, 0 < x_p <= L = {self.length:g} m (got {x_p!r}); "
                "the sphere has rolled off the beam"
            )
        return np.minimum(x, self.length)

    def _kz(self, x):
        return np.asarray(self.normal_stiffness(x), dtype=np.float64)

    def _kt(self, x):
        return np.asarray(self.torsional_stiffness(x), dtype=np.float64)

    # -- Eq. 5-8 and 13 ----------------------------------------------------------------------------
    def normal_force(self, x_p, end_deflection):
        """Force of the sphere on the beam at x_p from the end deflection (Eq. 5, 7, 8).

        .. math:: F_z(x_p) = k_z(x_p)\\,\\frac{2x_p}{3L - x_p}\\,\\delta(L, 0)

        Parameters
        ----------
        x_p : float or array, metres, in (0, L]
        end_deflection : float or array, metres
            delta(L, 0), measured by the photodiode (Eq. 2).

        Returns
        -------
        float or array, newtons
        """
        x = self._x(x_p)
        d = _finite_array("end_deflection", end_deflection, "metres")
        L = self.length
        # 2x / (3L - x) written so that it is exactly 1 at x = L
        return _out(self._kz(x) * (2.0 * x / (2.0 * L + (L - x))) * d)

    def force_x(self, x_p, end_deflection, offset: bool = True):
        """Longitudinal rendered force F_e^x (Eq. 13), zero at the extremity when ``offset``.

        Returns the Fig. 2a profile (positive, growing towards the clamp); the force on the haptic
        handle is its negative (see :meth:`haptic_force`).
        """
        f = np.asarray(self.normal_force(x_p, end_deflection))
        if offset:
            d = _finite_array("end_deflection", end_deflection, "metres")
            f = f - self._kz(self.length) * d
        return _out(f)

    def force_y(self, torsion):
        """Lateral rendered force F_e^y = k_tphi(L) phi(L, 0) / (w/2) (Eq. 14); newtons.

        Parameters
        ----------
        torsion : float or array, radians
            phi(L, 0), measured by the photodiode (Eq. 3).
        """
        phi = _finite_array("torsion", torsion, "radians")
        return _out(self._kt(self.length) * phi / (0.5 * self.width))

    # -- forward model ---------------------------------------------------------------------------
    def torsion(self, x_p, y_p, end_deflection):
        """Twist at the free end, phi(L, 0), for the sphere at (x_p, y_p) (forward model).

        .. math:: \\phi(L, 0) = \\frac{F_z(x_p)\\,y_p}{k_{t\\phi}(x_p)}
        """
        x = self._x(x_p)
        y = _finite_array("y_p", y_p, "metres from the middle line")
        return _out(np.asarray(self.normal_force(x, end_deflection)) * y / self._kt(x))

    def haptic_force(self, x_p, y_p, end_deflection, torsion=None):
        """Force on the handle's (x, y) axes, restoring towards the extremity and the middle line.

        Parameters
        ----------
        x_p, y_p : float or array, metres
            Load point on the beam (from the clamp; from the middle line).
        end_deflection : float or array, metres
            Measured delta(L, 0).
        torsion : float or array, radians, optional
            Measured phi(L, 0); computed with :meth:`torsion` when not given.

        Returns
        -------
        (..., 2) array, newtons: ``(-F_e^x, F_e^y)``.
        """
        phi = self.torsion(x_p, y_p, end_deflection) if torsion is None else torsion
        fx = -np.asarray(self.force_x(x_p, end_deflection))
        fy = np.asarray(self.force_y(phi))
        fx, fy = np.broadcast_arrays(fx, fy)
        return np.stack([fx, fy], axis=-1)


@dataclass(frozen=True)
class RollingFeedback:
    """One step of 2D rolling: where the sphere is on the beam and what the handle feels.

    Attributes
    ----------
    load_point : (..., 2) float, metres
        (x_p, y_p) on the beam.
    force : (..., 2) float, newtons
        Force on the handle's x and y axes (zero where the sphere is off the beam).
    on_beam : bool or (...,) bool
        False once the estimated load point has left the beam (:math:`x_p` outside (0, L] or :math:`|y_p| > w/2`).
    """

    load_point: np.ndarray
    force: np.ndarray
    on_beam: np.ndarray


class SphereRolling:
    """2D rolling of a sphere under a tipless cantilever, rendered on two haptic axes ([Bolopion]).

    The cantilever starts at ``cantilever0`` with the sphere at ``load_point0`` on the beam
    ([Bolopion] starts at the extremity, ``(L, 0)``, where no torsion is measured). Each call to
    :meth:`update` takes the cantilever position (nanotranslator sensors) and the measured end
    deflection and twist, and returns the estimated load point and the handle force.

    Parameters
    ----------
    probe : RollingProbe
    cantilever0 : (2,) float, metres
        Cantilever (x_c, y_c) at j = 0.
    load_point0 : (2,) float, metres
        Sphere load point (x_p, y_p) on the beam at j = 0; default the extremity (L, 0).

    Examples
    --------
    >>> probe = RollingProbe(220e-6, 27e-6, lambda x: 2.32 * (220e-6 / x) ** 3, lambda x: 64e-9 * 220e-6 / x)
    >>> roll = SphereRolling(probe, cantilever0=(0.0, 0.0))
    >>> fb = roll.update((40e-6, 0.0), end_deflection=0.7e-6, torsion=0.0)
    >>> [round(float(v) * 1e6, 1) for v in fb.load_point], bool(fb.force[0] < 0.0)
    ([200.0, 0.0], True)
    """

    def __init__(self, probe: RollingProbe, cantilever0, load_point0=None) -> None:
        if not isinstance(probe, RollingProbe):
            raise ManipulationError(f"probe must be a RollingProbe (got {type(probe).__name__})")
        c0 = _finite_array("cantilever0", cantilever0, "metres")
        p0 = _finite_array("load_point0", (probe.length, 0.0) if load_point0 is None else load_point0, "metres")
        if c0.shape != (2,) or p0.shape != (2,):
            raise ManipulationError(
                f"cantilever0 and load_point0 must be (x, y) pairs in metres (got shapes {c0.shape}, {p0.shape})"
            )
        if not (0.0 < p0[0] <= probe.length and abs(p0[1]) <= 0.5 * probe.width):
            raise ManipulationError(
                f"load_point0 must be on the beam, 0 < x_p <= {probe.length:g} m and |y_p| <= {0.5 * probe.width:g} m "
                f"(got {p0.tolist()})"
            )
        self.probe = probe
        self.cantilever0 = c0
        self.load_point0 = p0

    def load_point(self, cantilever) -> np.ndarray:
        """(..., 2) load point for cantilever positions (..., 2) (Eq. 12, beam frame, both axes)."""
        c = _finite_array("cantilever", cantilever, "metres")
        if c.shape[-1:] != (2,):
            raise ManipulationError(f"cantilever must have shape (2,) or (n, 2) in metres (got {c.shape})")
        return self.load_point0 - 0.5 * (c - self.cantilever0)

    def update(self, cantilever, end_deflection, torsion=None) -> RollingFeedback:
        """Estimate the load point and render the handle force for cantilever positions.

        Parameters
        ----------
        cantilever : (2,) or (n, 2) float, metres
        end_deflection : float or (n,) float, metres
            Measured delta(L, 0) (servoed constant in [Bolopion]).
        torsion : float or (n,) float, radians, optional
            Measured phi(L, 0); when omitted it is simulated with the forward model
            (:meth:`RollingProbe.torsion`), for a virtual experiment.

        Returns
        -------
        RollingFeedback
        """
        p = self.load_point(cantilever)
        x, y = p[..., 0], p[..., 1]
        on = (x > 0.0) & (x <= self.probe.length * (1.0 + 1e-12)) & (np.abs(y) <= 0.5 * self.probe.width)
        xs = np.where(on, x, self.probe.length)  # evaluate safely, then zero off the beam
        d = _finite_array("end_deflection", end_deflection, "metres")
        phi = None if torsion is None else _finite_array("torsion", torsion, "radians")
        f = self.probe.haptic_force(xs, np.where(on, y, 0.0), d, phi)
        f = np.where(on[..., None], f, 0.0)
        return RollingFeedback(p, f, on if on.ndim else bool(on))
