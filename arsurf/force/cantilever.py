"""Rectangular AFM cantilever: stiffnesses, load-point formulas and the forward force -> angles model.

Frame (docs/design.rst, "Units and conventions"; [Alabdulmuhsin] Fig. 2.1): x runs along the beam from the clamp to the free
end, y is lateral, z points out of the sample (up). The tip hangs below the free end; its apex is at a
distance ``lever_arm = tip_height + thickness/2`` below the beam's neutral axis ([MWCNT] uses
the same lever arm, ``h_t + b/2``). A force ``F = (F_x, F_y, F_z)`` is the force *of the sample on
the tip apex*, in newtons.

The optical lever measures two angles at the free end:

.. math::

    \\Delta\\alpha = \\frac{l^2}{2EI}\\Big(F_z + \\frac{2a}{l} F_x\\Big), \\qquad
    \\Delta\\theta = c\\,F_y, \\quad c = \\frac{a}{k_{t\\phi}},

the bending (end slope of an Euler-Bernoulli beam loaded by the end force F_z and the end moment
a F_x, positive when the end tilts towards +z) and the torsion (twist about x, positive for a
positive moment a F_y). [SplineAR] Eq. 1-2, completed in docs/design.rst, "Force from the two angles".

Stiffness at a load point x_p ([Bolopion], Eq. 4-11): ``k_z(x_p) = (L/x_p)^3 k_z(L)`` and
``k_tphi(x_p) = G beta w t^3 / x_p``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from arsurf import _validation
from arsurf.errors import ForceError

__all__ = [
    "Cantilever",
    "TORSION_TABLE",
    "torsion_coefficient",
    "torsional_stiffness_from_geometry",
]

# Torsion of a solid rectangular bar, J = beta * long * short^3: the standard table of beta
# against the side ratio long/short (Timoshenko & Goodier, "Theory of Elasticity", 3rd ed.,
# sec. 109, Table 6, coefficient k1; the same values are in Roark's "Formulas for Stress and
# Strain", Table 10.7 case 4). The last row is the thin-strip limit 1/3 (ratio -> infinity).
TORSION_TABLE = np.array(
    [
        # long/short, beta
        [1.0, 0.141],
        [1.2, 0.166],
        [1.5, 0.196],
        [2.0, 0.229],
        [2.5, 0.249],
        [3.0, 0.263],
        [4.0, 0.281],
        [5.0, 0.291],
        [10.0, 0.312],
        [np.inf, 1.0 / 3.0],
    ]
)


def torsion_coefficient(aspect: float, method: str = "series") -> float:
    """Torsion coefficient beta of a solid rectangle, ``J = beta * w * t^3`` (w >= t).

    .. math::

        \\beta = \\frac{1}{3}\\Big[1 - \\frac{192}{\\pi^5}\\frac{t}{w}
        \\sum_{n=1,3,5,\\dots}\\frac{1}{n^5}\\tanh\\frac{n\\pi w}{2t}\\Big]

    (Saint-Venant's series, Timoshenko & Goodier sec. 109). ``method="table"`` interpolates the
    standard table :data:`TORSION_TABLE` linearly in t/w; ``method="roark"`` is Roark's closed
    approximation ``beta = 1/3 - 0.21 (t/w) (1 - (t/w)^4 / 12)``.

    Parameters
    ----------
    aspect : float
        Short side over long side, t/w, in (0, 1]. A value above 1 is inverted (the formula is
        symmetric once the long side is taken as w).
    method : {"series", "table", "roark"}

    Returns
    -------
    float
        beta, dimensionless; 0.1406 for a square, 1/3 for a thin strip.

    Examples
    --------
    >>> round(torsion_coefficient(1.0), 4)
    0.1406
    """
    aspect = float(aspect)
    if not (math.isfinite(aspect) and aspect > 0.0):
        raise ForceError(
            f"the side ratio t/w must be positive and finite (got {aspect!r}); "
            "pass thickness / width of the beam"
        )
    r = aspect if aspect <= 1.0 else 1.0 / aspect
    if method == "series":
        total = 0.0
        for n in range(1, 80, 2):
            total += math.tanh(n * math.pi / (2.0 * r)) / n**5
        return (1.0 - 192.0 / math.pi**5 * r * total) / 3.0
    if method == "table":
        x = 1.0 / TORSION_TABLE[::-1, 0]  # t/w, increasing from 0 (thin strip) to 1 (square)
        return float(np.interp(r, x, TORSION_TABLE[::-1, 1]))
    if method == "roark":
        return 1.0 / 3.0 - 0.21 * r * (1.0 - r**4 / 12.0)
    raise ForceError(f"method must be 'series', 'table' or 'roark' (got {method!r})")


def torsional_stiffness_from_geometry(
    length: float, width: float, thickness: float, shear_modulus: float, beta: float | None = None
) -> float:
    """Torsional spring constant of a rectangular beam twisted about its axis.

    .. math:: k_{t\\phi} = \\frac{G\\,\\beta\\,w\\,t^3}{l}

    ([MWCNT] Eq. 8 after Case et al.; [Bolopion] Eq. 10 with beta = 1/3).

    Parameters
    ----------
    length, width, thickness : float, metres
        Twisted length l (the load point x_p for a load away from the end), width w, thickness t.
    shear_modulus : float, pascals
        G = E / (2 (1 + nu)) for an isotropic beam.
    beta : float, optional
        Torsion coefficient; by default :func:`torsion_coefficient` of t/w (series). Pass 1/3 for
        the thin-plate value used by [Bolopion].

    Returns
    -------
    float, N m / rad

    Examples
    --------
    >>> G = 150e9 / (2 * 1.17)
    >>> round(torsional_stiffness_from_geometry(220e-6, 27e-6, 2.9e-6, G, beta=1/3) * 1e9, 1)
    64.0
    """
    _check_positive(length=length, width=width, thickness=thickness, shear_modulus=shear_modulus)
    if beta is None:
        beta = torsion_coefficient(thickness / width)
    elif not (math.isfinite(beta) and 0.0 < beta <= 1.0 / 3.0 + 1e-12):
        raise ForceError(f"beta must be in (0, 1/3] (got {beta!r}); 1/3 is the thin-strip limit")
    return shear_modulus * beta * width * thickness**3 / length


def _check_positive(**values: float) -> None:
    for name, value in values.items():
        _validation.positive(value, name, ForceError, hint="cantilever geometry and moduli are SI (metres, pascals)")


@dataclass(frozen=True)
class Cantilever:
    """A rectangular AFM cantilever with a tip at its free end.

    Parameters
    ----------
    length, width, thickness : float, metres
        Beam length l (clamp to tip), width w and thickness t; all > 0.
    tip_height : float, metres
        Height of the tip below the beam's lower face (>= 0; 0 is a tipless lever, [Bolopion]).
    youngs_modulus : float, pascals
        E (169 GPa for silicon along <110>; [Bolopion] uses 150 GPa).
    poisson_ratio : float
        nu in (-1, 0.5); G = E / (2 (1 + nu)).
    normal_stiffness : float, optional, N/m
        A calibrated normal spring constant k (thermal noise, manufacturer); it overrides the
        geometric value and sets the effective flexural rigidity EI = k l^3 / 3.
    torsional_stiffness : float, optional, N m / rad
        A calibrated torsional constant overriding G beta w t^3 / l.
    beta : float, optional
        Torsion coefficient; default :func:`torsion_coefficient` (t / w). [Bolopion] uses 1/3.

    Examples
    --------
    >>> lever = Cantilever(220e-6, 27e-6, 2.9e-6, 0.0, 150e9, 0.17, beta=1/3)
    >>> round(lever.normal_stiffness, 2), round(lever.torsional_stiffness * 1e9, 1)
    (2.32, 64.0)
    >>> bending, torsion = lever.angles([0.0, 0.0, 1e-6])
    """

    length: float
    width: float
    thickness: float
    tip_height: float
    youngs_modulus: float
    poisson_ratio: float
    normal_stiffness: float | None = field(default=None)
    torsional_stiffness: float | None = field(default=None)
    beta: float | None = field(default=None)

    def __post_init__(self) -> None:
        _check_positive(
            length=self.length, width=self.width, thickness=self.thickness,
            youngs_modulus=self.youngs_modulus,
        )
        for name in ("length", "width", "thickness", "youngs_modulus"):
            object.__setattr__(self, name, float(getattr(self, name)))
        h = _as_float("tip_height", self.tip_height)
        if not (math.isfinite(h) and h >= 0.0):
            raise ForceError(
                f"tip_height must be >= 0 and finite (got {self.tip_height!r} m); use 0 for a tipless lever"
            )
        object.__setattr__(self, "tip_height", h)
        nu = _as_float("poisson_ratio", self.poisson_ratio)
        if not (math.isfinite(nu) and -1.0 < nu < 0.5):
            raise ForceError(
                f"poisson_ratio must be in (-1, 0.5) for an isotropic solid (got {self.poisson_ratio!r}); "
                "silicon is about 0.17-0.28"
            )
        object.__setattr__(self, "poisson_ratio", nu)
        if self.beta is None:
            object.__setattr__(self, "beta", torsion_coefficient(self.thickness / self.width))
        else:
            b = _as_float("beta", self.beta)
            if not (math.isfinite(b) and 0.0 < b <= 1.0 / 3.0 + 1e-12):
                raise ForceError(f"beta must be in (0, 1/3] (got {self.beta!r}); 1/3 is the thin-strip limit")
            object.__setattr__(self, "beta", b)
        E, w, t, l = self.youngs_modulus, self.width, self.thickness, self.length
        if self.normal_stiffness is None:
            object.__setattr__(self, "normal_stiffness", E * w * t**3 / (4.0 * l**3))
        else:
            _check_positive(normal_stiffness=self.normal_stiffness)
            object.__setattr__(self, "normal_stiffness", float(self.normal_stiffness))
        if self.torsional_stiffness is None:
            object.__setattr__(self, "torsional_stiffness", self.shear_modulus * self.beta * w * t**3 / l)
        else:
            _check_positive(torsional_stiffness=self.torsional_stiffness)
            object.__setattr__(self, "torsional_stiffness", float(self.torsional_stiffness))

    # ---- material and section -------------------------------------------------------------
    @property
    def shear_modulus(self) -> float:
        """G = E / (2 (1 + nu)), pascals."""
        return self.youngs_modulus / (2.0 * (1.0 + self.poisson_ratio))

    @property
    def second_moment(self) -> float:
        """Second moment of area for bending out of plane, I = w t^3 / 12 (m^4; [Bolopion]'s I_y)."""
        return self.width * self.thickness**3 / 12.0

    @property
    def flexural_rigidity(self) -> float:
        """EI (N m^2): geometric, or k l^3 / 3 when a calibrated normal stiffness is given."""
        return self.normal_stiffness * self.length**3 / 3.0

    @property
    def lever_arm(self) -> float:
        """Distance a from the tip apex to the beam's neutral axis, tip_height + thickness / 2 (m)."""
        return self.tip_height + 0.5 * self.thickness

    # ---- load point along the beam ([Bolopion]) ---------------------------------------------
    def _check_load_point(self, x_p) -> np.ndarray:
        x = np.asarray(x_p, dtype=np.float64)
        if not np.all(np.isfinite(x)) or np.any(x <= 0.0) or np.any(x > self.length * (1 + 1e-12)):
            raise ForceError(
                f"load point x_p must lie in (0, length = {self.length:g} m] (got {x_p!r}); "
                "x is measured from the clamp"
            )
        return x

    def normal_stiffness_at(self, x_p):
        """Normal stiffness for a load at x_p, measured at x_p ([Bolopion] Eq. 6).

        .. math:: k_z(x_p) = \\frac{E w t^3}{4 x_p^3} = \\Big(\\frac{L}{x_p}\\Big)^3 k_z(L)

        Parameters
        ----------
        x_p : float or array, metres, in (0, length]

        Returns
        -------
        float or array, N/m
        """
        x = self._check_load_point(x_p)
        out = (self.length / x) ** 3 * self.normal_stiffness
        return float(out) if out.ndim == 0 else out

    def torsional_stiffness_at(self, x_p):
        """Torsional spring for a moment applied at x_p ([Bolopion] Eq. 10): k_tphi(L) L / x_p (N m/rad)."""
        x = self._check_load_point(x_p)
        out = self.torsional_stiffness * self.length / x
        return float(out) if out.ndim == 0 else out

    def deflection(self, x, x_p, force):
        """Deflection delta(x) of the beam under a normal force at x_p ([Bolopion] Eq. 4).

        .. math::

            \\delta(x) = \\frac{F}{EI}\\Big(\\frac{x\\,x_p^2}{2} - \\frac{x_p^3}{6}\\Big) \\; (x \\ge x_p),
            \\qquad \\delta(x) = \\frac{F x^2 (3 x_p - x)}{6 EI} \\; (x < x_p).

        Parameters
        ----------
        x : float or array, metres, in [0, length]
        x_p : float, metres, in (0, length]
        force : float, newtons (positive along +z)

        Returns
        -------
        float or array, metres
        """
        xp = float(self._check_load_point(x_p))
        xs = np.asarray(x, dtype=np.float64)
        if not np.all(np.isfinite(xs)) or np.any(xs < 0.0) or np.any(xs > self.length * (1 + 1e-12)):
            raise ForceError(f"x must lie in [0, length = {self.length:g} m] (got {x!r})")
        f = _as_float("force", force)
        ei = self.flexural_rigidity
        out = np.where(
            xs >= xp,
            f / ei * (xs * xp**2 / 2.0 - xp**3 / 6.0),
            f * xs**2 * (3.0 * xp - xs) / (6.0 * ei),
        )
        return float(out) if out.ndim == 0 else out

    def force_from_end_deflection(self, x_p, end_deflection):
        """Normal force at x_p from the deflection measured at the free end ([Bolopion] Eq. 8, 13).

        .. math:: F_z(x_p) = \\frac{2L^3}{x_p^2 (3L - x_p)}\\, k_z(L)\\, \\delta(L)

        Examples
        --------
        >>> lever = Cantilever(220e-6, 27e-6, 2.9e-6, 0.0, 150e9, 0.17, normal_stiffness=2.4)
        >>> round(lever.force_from_end_deflection(220e-6, 0.7e-6) * 1e6, 2)
        1.68
        """
        x = self._check_load_point(x_p)
        d = np.asarray(end_deflection, dtype=np.float64)
        if not np.all(np.isfinite(d)):
            raise ForceError(f"end_deflection must be finite (got {end_deflection!r})")
        L = self.length
        out = 2.0 * L**3 / (x**2 * (3.0 * L - x)) * self.normal_stiffness * d
        return float(out) if out.ndim == 0 else out

    # ---- forward model ([SplineAR], docs/design.rst, "Force from the two angles") -----------------------
    @property
    def bending_compliance(self) -> float:
        """g = l^2 / (2 EI): end slope per newton of end force (rad/N)."""
        return self.length**2 / (2.0 * self.flexural_rigidity)

    @property
    def torsion_compliance(self) -> float:
        """c = a / k_tphi: twist per newton of lateral force at the apex (rad/N)."""
        return self.lever_arm / self.torsional_stiffness

    @property
    def coupling(self) -> float:
        """kappa = 2 a / l: how much of F_x the bending signal sees, relative to F_z."""
        return 2.0 * self.lever_arm / self.length

    def angles(self, force):
        """Bending and torsion angles produced by a force on the tip apex.

        .. math::

            \\Delta\\alpha = \\frac{l^2}{2EI}\\Big(F_z + \\frac{2a}{l}F_x\\Big), \\qquad
            \\Delta\\theta = \\frac{a}{k_{t\\phi}}\\,F_y

        Parameters
        ----------
        force : (3,) or (n, 3) float, newtons
            Force of the sample on the tip, (F_x, F_y, F_z) in the cantilever frame.

        Returns
        -------
        bending, torsion : float or (n,) float, radians

        Examples
        --------
        >>> lever = Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27)
        >>> b, t = lever.angles([0.0, 1e-9, 0.0])
        >>> b == 0.0 and t > 0.0
        True
        """
        f = np.asarray(force, dtype=np.float64)
        if f.shape[-1:] != (3,) or f.ndim > 2:
            raise ForceError(f"force must have shape (3,) or (n, 3) (got {f.shape}); it is (F_x, F_y, F_z) in N")
        if not np.all(np.isfinite(f)):
            raise ForceError("force has NaN or infinite components; pass finite newtons")
        bending = self.bending_compliance * (f[..., 2] + self.coupling * f[..., 0])
        torsion = self.torsion_compliance * f[..., 1]
        if f.ndim == 1:
            return float(bending), float(torsion)
        return bending, torsion

    def kernel_parameters(self) -> tuple[float, float, float]:
        """(g, kappa, c) = (bending_compliance, coupling, torsion_compliance) for the kernels."""
        return self.bending_compliance, self.coupling, self.torsion_compliance


def _as_float(name: str, value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ForceError(f"{name} must be a number (got {value!r})") from None
