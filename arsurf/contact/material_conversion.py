r"""From an instrument's mechanical channels to contact parameters: reduced modulus and work of adhesion.

A PeakForce QNM (Bruker), QI (JPK) or force-volume (Asylum) image holds, per pixel, a *sample*
modulus fitted by the instrument and the *pull-off force* of the retract curve. The contact
model takes the reduced modulus :math:`E^*` and the work of adhesion *w* (DESIGN.md). This
module converts one into the other, with every assumption a parameter of
:class:`MaterialConversion` (recorded in a session, so a replay converts the same way).

**Units first.** A channel in SI (``Pa``, ``N``) is used as it is. A channel the file leaves
uncalibrated is never read as if it were SI: ``Arb`` needs a stated scale (``modulus_scale``
Pa per Arb, ``adhesion_scale`` N per Arb), an adhesion in volts of photodiode deflection needs
the deflection sensitivity (m/V) and the spring constant (N/m), :math:`F = V S k`, an adhesion
in metres of deflection needs the spring constant. Anything else is refused with the conversion
that is missing (:func:`channel_to_si`).

**Modulus.** NanoScope's ``DMTModulus`` is the sample's Young modulus :math:`E_s` from a DMT fit
of the retract curve that assumes a rigid tip, with the sample Poisson ratio the file's header
states (Bruker's *PeakForce QNM User Guide*; JPK and Asylum report the same quantity): the fit
measures the reduced modulus :math:`E^*` of that probe on that sample and writes
:math:`E_s = E^*(1-\nu_s^2)`. The real tip's compliance is therefore already inside the
measured :math:`E^*`; for the probe that measured the map (``probe="same"``, the default: the AR
tip is the instrument's)

.. math:: E^* = \frac{E_s}{1-\nu_s^2}.

Combining with a tip's compliance again (Johnson 1985, Eq. 4.22; :mod:`arsurf.contact.materials`)

.. math:: \frac{1}{E^*} = \frac{1-\nu_s^2}{E_s} + \frac{1-\nu_t^2}{E_t}

is the explicit option ``probe="other"``, for a map measured with another probe: :math:`E_s` is
then taken as the sample's own modulus (the fit's rigid-tip assumption) under a tip of modulus
:math:`E_t`, ratio :math:`\nu_t` (default :data:`arsurf.contact.materials.MATERIALS` ``"Si"``:
130 GPa, 0.28). Counting the silicon tip twice lowered :math:`E^*` by 0.8 % at
:math:`E_s` = 1 GPa, 6.6 % at 9 GPa, 23 % at 39 GPa. :math:`\nu_s`: ``sample_poisson`` when
stated, else the file's *Sample Poisson's Ratio* (NanoScope header), else 0.3 (NanoScope's
default); the map says which (:mod:`arsurf.contact.material_map`).

**Two modulus channels.** A QNM file holds the modulus twice, linear (``DMTModulus``) and as its
base-10 logarithm (``LogDMTModulus``). Where both exist the map compares them pixel by pixel
(``cross_check``): ``"mask"`` (default) masks the pixels where they disagree, ``"log"`` reads
the logarithmic channel everywhere (it keeps the dynamic range), ``"off"`` does not compare
(:func:`arsurf.contact.material_map.channel_disagreement`).

**Adhesion.** The pull-off force :math:`F` (> 0, the most tensile load of the retract curve)
gives *w* through the pull-off load of the contact regime at the tip radius *R*:

.. math:: F = 2\pi R w \;(\text{DMT}), \qquad F = \tfrac32 \pi R w \;(\text{JKR}), \qquad
          F = -\bar P_c(\lambda)\, \pi R w \;(\text{Maugis-Dugdale}),

with :math:`\bar P_c(\lambda) \in [-2, -1.5]` the MD pull-off of :mod:`arsurf.contact.maugis_dugdale`
(:func:`~arsurf.contact.maugis_dugdale.md_critical_point_kernel`). In MD,
:math:`\lambda = 2\sigma_0 (R/\pi w K^2)^{1/3}` depends on *w* itself; with the Dugdale range
:math:`h_0 = w/\sigma_0` held fixed (``dugdale_range``, default
:math:`9\sqrt3 z_0/16` = 0.292 nm, the range of :func:`~arsurf.contact.materials.default_dugdale_stress`),
:math:`\lambda = (2/h_0)\, w^{2/3} (R/\pi K^2)^{1/3}`, and *w* is the fixed point of
:math:`w = F / (-\bar P_c(\lambda(w))\,\pi R)`, a contraction (:math:`|d\ln\bar P_c/d\ln w| < 0.1`):
from the DMT value, about 12 iterations reach 1e-14. :math:`\bar P_c` is read by linear
interpolation, every 2e-4 in :math:`\ln\lambda`, from a cubic spline through its exact values at 50
points per unit over :math:`\lambda \in [10^{-6}, 10^6]` (relative error < 1e-9, tested), so a
1024² image converts in about a second. A pull-off at or below zero is below the instrument's
detection (noise around a non-adhesive pixel): pull-offs below ``adhesion_floor`` are raised
to it and counted (default: the rms of the negative pull-offs of the processed field, the
noise's own estimate; :mod:`arsurf.contact.material_map`).

Sources: K. L. Johnson, *Contact Mechanics* (1985) Eq. 4.22; B. V. Derjaguin, V. M. Muller,
Yu. P. Toporov (1975); K. L. Johnson, K. Kendall, A. D. Roberts (1971); D. Maugis, J. Colloid
Interface Sci. 150, 243 (1992); Bruker, *PeakForce QNM User Guide* (DMT modulus, adhesion).

Examples
--------
>>> conv = MaterialConversion(tip_radius=10e-9, regime="dmt")
>>> round(float(work_of_adhesion_from_pull_off(2 * 3.141592653589793 * 10e-9 * 0.05, 1e9, conv)), 12)
0.05
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from arsurf import _validation
from arsurf.contact.materials import DEFAULT_EQUILIBRIUM_SPACING, MATERIALS
from arsurf.errors import MaterialMapError

__all__ = [
    "CROSS_CHECKS",
    "DEFAULT_DUGDALE_RANGE",
    "DEFAULT_SAMPLE_POISSON",
    "MaterialConversion",
    "PROBES",
    "REGIMES",
    "channel_to_si",
    "pull_off_bar",
    "reduced_modulus",
    "work_of_adhesion_from_pull_off",
]

#: NanoScope's default *Sample Poisson's Ratio* for the DMT fit (written in a QNM file's header)
DEFAULT_SAMPLE_POISSON = 0.3
#: Dugdale range h0 = w / sigma0 of the default Dugdale stress 16 w / (9 sqrt(3) z0): 0.974 z0
DEFAULT_DUGDALE_RANGE = 9.0 * math.sqrt(3.0) * DEFAULT_EQUILIBRIUM_SPACING / 16.0
#: contact regimes for the adhesion -> w conversion
REGIMES = ("md", "dmt", "jkr")
#: whose modulus E* is: the probe that measured the map (the fit's own E*) or another tip combined with E_s
PROBES = ("same", "other")
#: what to do where the linear and the logarithmic modulus channels disagree
CROSS_CHECKS = ("mask", "log", "off")
#: the values a recording made before ``probe`` and ``cross_check`` existed was converted with
#: (the silicon tip combined, no cross-check): :meth:`MaterialConversion.from_metadata` fills them in
LEGACY = {"probe": "other", "cross_check": "off"}
#: the unit of each parameter, for the summaries (JSON keys with their unit)
#: (a scale is SI per unit of a channel the file leaves uncalibrated: Pa per Arb is named ``_Pa``)
_UNITS = {"tip_radius": "m", "tip_modulus": "Pa", "dugdale_range": "m", "modulus_scale": "Pa",
          "adhesion_scale": "N", "deflection_sensitivity": "m_per_V", "spring_constant": "N_per_m",
          "adhesion_floor": "N", "deformation_scale": "m", "dissipation_scale": "J"}
_TIP = MATERIALS["Si"]
#: the channel roles of a map (``--<role>-channel`` flags): log_modulus is the cross-check's
ROLES = ("modulus", "log_modulus", "adhesion", "deformation", "dissipation")
#: the MD pull-off table: ln(lambda) from -ln(1e6) to ln(1e6), 50 nodes per unit
_LAM_LIMITS = (1e-6, 1e6)
_TABLE_PER_UNIT = 50
_FINE_PER_UNIT = 5000


@dataclass(frozen=True)
class MaterialConversion:
    """How a scan's mechanical channels become E* and w (SI units; JSON-able for a session).

    Parameters
    ----------
    tip_radius : float, m
        Tip radius R of the adhesion conversion (the AR model's tip: the same probe).
    sample_poisson : float, optional
        Sample Poisson ratio of the instrument's DMT fit. None (default): the file's header
        (NanoScope *Sample Poisson's Ratio*), else 0.3 (NanoScope's default).
    probe : {"same", "other"}
        ``"same"`` (default): the map was measured with the AR model's tip, E* = E_s/(1 - nu_s^2)
        (the rigid-tip fit's own E*). ``"other"``: another probe measured it; E_s is combined
        with the tip of ``tip_modulus``, ``tip_poisson`` (Johnson Eq. 4.22).
    tip_modulus, tip_poisson : float, Pa and -
        The tip's elastic constants for ``probe="other"`` (default silicon, ``MATERIALS["Si"]``:
        130 GPa, 0.28).
    cross_check : {"mask", "log", "off"}
        Where the file has the modulus twice (``DMTModulus``, ``LogDMTModulus``): mask the pixels
        where they disagree (default), read the log channel everywhere, or do not compare.
    regime : {"md", "dmt", "jkr"}
        Pull-off law of the adhesion conversion (default Maugis-Dugdale at the local E*).
    dugdale_range : float, m
        :math:`h_0 = w/\\sigma_0`, the same everywhere on the map (default 0.292 nm).
    modulus_scale : float, Pa per channel unit, optional
        Needed when the modulus channel is not in Pa (``Arb``): the file's own calibration.
    adhesion_scale : float, N per channel unit, optional
        Needed for an adhesion channel in ``Arb``.
    deflection_sensitivity : float, m/V, optional
    spring_constant : float, N/m, optional
        Needed for an adhesion channel in V (both) or in m of deflection (the spring constant).
    adhesion_floor : float, N, optional
        Pull-offs below it are raised to it (default: the rms of the negative ones).
    outlier_mads : float
        A modulus pixel farther than this many robust standard deviations (1.4826 MAD) from
        the median of log E is an outlier (masked and filled); default 6.
    deformation_scale, dissipation_scale : float, optional
        SI per channel unit for the viewer's deformation (m) and dissipation (J) maps; without
        them those maps stay in the channel's unit.
    """

    tip_radius: float
    sample_poisson: float | None = None
    probe: str = "same"
    tip_modulus: float = _TIP.youngs_modulus
    tip_poisson: float = _TIP.poisson_ratio
    regime: str = "md"
    dugdale_range: float = DEFAULT_DUGDALE_RANGE
    modulus_scale: float | None = None
    adhesion_scale: float | None = None
    deflection_sensitivity: float | None = None
    spring_constant: float | None = None
    adhesion_floor: float | None = None
    outlier_mads: float = 6.0
    deformation_scale: float | None = None
    dissipation_scale: float | None = None
    cross_check: str = "mask"

    def __post_init__(self) -> None:
        def pos(name, unit, hint):
            object.__setattr__(self, name, _validation.positive(getattr(self, name), name, MaterialMapError,
                                                                unit=unit, hint=hint))

        pos("tip_radius", "m", "the radius of the tip that measured the map (the AR tip)")
        pos("tip_modulus", "Pa", "the tip's Young modulus")
        pos("dugdale_range", "m", "the Dugdale range h0 = w / sigma0, ~0.3 nm")
        pos("outlier_mads", "", "robust standard deviations of log E beyond which a pixel is an outlier")
        for name in ("sample_poisson", "tip_poisson"):
            if getattr(self, name) is None and name == "sample_poisson":
                continue
            object.__setattr__(self, name, check_poisson(getattr(self, name), name))
        for name, choices, what in (("probe", PROBES, "whose E* the map gives: the probe that measured it "
                                                      "(same) or another tip (other)"),
                                    ("cross_check", CROSS_CHECKS, "what to do where the linear and the log "
                                                                  "modulus channels disagree")):
            if getattr(self, name) not in choices:
                raise MaterialMapError(f"{name} must be one of {choices} (got {getattr(self, name)!r}); it is {what}")
        if self.regime not in REGIMES:
            raise MaterialMapError(f"regime must be one of {REGIMES} (got {self.regime!r}); it is the pull-off law "
                                   "of the adhesion conversion")
        for name, unit in (("modulus_scale", "Pa per channel unit"), ("adhesion_scale", "N per channel unit"),
                           ("deflection_sensitivity", "m/V"), ("spring_constant", "N/m"),
                           ("deformation_scale", "m per channel unit"), ("dissipation_scale", "J per channel unit")):
            if getattr(self, name) is not None:
                pos(name, unit, "a conversion stated by the user")
        if self.adhesion_floor is not None:
            object.__setattr__(self, "adhesion_floor", _validation.positive(
                self.adhesion_floor, "adhesion_floor", MaterialMapError, unit="N",
                hint="the smallest pull-off force the instrument resolves"))

    def to_metadata(self) -> dict:
        """The parameters as a JSON object (SI units)."""
        return dataclasses.asdict(self)

    def summary(self) -> dict:
        """The parameters as a JSON object whose keys name their SI unit (``tip_radius_m``...)."""
        return {(f"{k}_{_UNITS[k]}" if k in _UNITS else k): v for k, v in dataclasses.asdict(self).items()}

    def with_sample_poisson(self, header) -> tuple["MaterialConversion", str]:
        """``(conversion, source)``: this conversion with its sample Poisson ratio resolved.

        Stated (``sample_poisson`` not None) wins; else the file's header value ``header``
        (refused when it is not a Poisson ratio); else :data:`DEFAULT_SAMPLE_POISSON`. ``source``
        says which, for the map's legend and summary."""
        if self.sample_poisson is not None:
            return self, "stated"
        if header is None:
            return dataclasses.replace(self, sample_poisson=DEFAULT_SAMPLE_POISSON), \
                "default (NanoScope's; the file states none)"
        try:
            nu = check_poisson(header, "the file's Sample Poisson's Ratio")
        except MaterialMapError as exc:
            raise MaterialMapError(f"{exc}; state the ratio the fit used with sample_poisson (CLI --sample-poisson)") \
                from None
        return dataclasses.replace(self, sample_poisson=nu), "file header (Sample Poisson's Ratio)"

    @classmethod
    def from_metadata(cls, meta: Mapping[str, Any]) -> "MaterialConversion":
        """Rebuild from :meth:`to_metadata` (unknown keys are refused)."""
        if not isinstance(meta, Mapping):
            raise MaterialMapError(f"a material conversion must be an object of parameters (got {meta!r})")
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(meta) - names)
        if unknown:
            raise MaterialMapError(f"unknown material conversion parameters {unknown}; known: {sorted(names)}")
        if "tip_radius" not in meta:
            raise MaterialMapError("the material conversion lacks tip_radius (m)")
        return cls(**{**LEGACY, **dict(meta)})  # a recording older than probe/cross_check: converted as it was

    # -- the command line (units at this edge: nm, GPa, nN, N/m) ------------------------------
    @staticmethod
    def cli_arguments(parser, tip_radius_nm: float | None = 20.0) -> None:
        """Add the conversion's flags and the channel names to an argparse parser (``arsurf
        info --material``, ``arsurf demo --material``, ``arsurf view --material``);
        :meth:`from_cli` reads them back. ``tip_radius_nm`` None: the parser has its own
        ``--tip-radius-nm``."""
        g = parser.add_argument_group("material map (mechanical channels -> E*, w)")
        if tip_radius_nm is not None:
            g.add_argument("--tip-radius-nm", type=_number_type("nm", 0.0), default=tip_radius_nm,
                           help=f"tip radius of the adhesion conversion and of the model, nm (default "
                                f"{tip_radius_nm:g})")
        flags = (("--modulus-scale", "PA_PER_UNIT", "pascals per unit of a modulus channel the file leaves "
                                                    "uncalibrated (Arb); never assumed"),
                 ("--adhesion-scale", "N_PER_UNIT", "newtons per unit of an adhesion channel in Arb"),
                 ("--deflection-sensitivity-nm-per-v", "NM_PER_V", "deflection sensitivity, for an adhesion "
                                                                    "channel in volts of deflection (F = V S k)"),
                 ("--spring-constant", "N_PER_M", "cantilever spring constant, for an adhesion channel in V or m"),
                 ("--tip-modulus-gpa", "GPA", "tip Young modulus, with --probe other (default silicon, 130 GPa)"),
                 ("--adhesion-floor-nn", "NN", "pull-offs below it are raised to it (default: rms of the negative "
                                               "ones)"))
        for flag, metavar, text in flags:
            g.add_argument(flag, type=_number_type("", 0.0), metavar=metavar, help=text)
        for flag, text in (("--sample-poisson", "sample Poisson ratio of the instrument's DMT fit (default: the "
                                                "file's header, else 0.3)"),
                           ("--tip-poisson", "tip Poisson ratio, with --probe other (default 0.28)")):
            g.add_argument(flag, type=_number_type("", -1.0, 0.5), metavar="NU", help=text)
        g.add_argument("--probe", default="same", choices=PROBES, help="same (default): the AR tip is the probe "
                       "that measured the map, E* = E_s/(1-nu_s^2) (the rigid-tip DMT fit's own E*); other: combine "
                       "E_s with the tip of --tip-modulus-gpa/--tip-poisson")
        g.add_argument("--cross-check", default="mask", choices=CROSS_CHECKS, help="where the linear and the log "
                       "modulus channels disagree: mask those pixels (default), read the log channel everywhere, or "
                       "off (do not compare)")
        g.add_argument("--regime", default="md", choices=REGIMES, help="pull-off law of the adhesion -> w "
                       "conversion (default md: Maugis-Dugdale at the local E*)")
        for role in ROLES:
            g.add_argument(f"--{role.replace('_', '-')}-channel", metavar="NAME", help=f"the {role.replace('_', ' ')} "
                           "channel (default: the PeakForce QNM name)")

    @classmethod
    def from_cli(cls, args) -> "MaterialConversion":
        """The conversion of the flags of :meth:`cli_arguments` (converted to SI)."""
        def opt(name, scale=1.0):
            v = getattr(args, name, None)
            return None if v is None else v * scale

        probe = getattr(args, "probe", "same")
        if probe != "other":
            given = [f for f, n in (("--tip-modulus-gpa", "tip_modulus_gpa"), ("--tip-poisson", "tip_poisson"))
                     if opt(n) is not None]
            if given:
                raise MaterialMapError(f"{' and '.join(given)} {'describe' if len(given) > 1 else 'describes'} another tip, but the map's E* is the measuring "
                                       "probe's own (--probe same, the default); add --probe other to combine the "
                                       "sample modulus with that tip, or leave them out")
        kw = {k: v for k, v in (("tip_poisson", opt("tip_poisson")), ("tip_modulus", opt("tip_modulus_gpa", 1e9)))
              if v is not None}
        return cls(tip_radius=args.tip_radius_nm * 1e-9, regime=args.regime, modulus_scale=opt("modulus_scale"),
                   sample_poisson=opt("sample_poisson"), probe=probe,
                   cross_check=getattr(args, "cross_check", "mask"),
                   adhesion_scale=opt("adhesion_scale"),
                   deflection_sensitivity=opt("deflection_sensitivity_nm_per_v", 1e-9),
                   spring_constant=opt("spring_constant"), adhesion_floor=opt("adhesion_floor_nn", 1e-9), **kw)

    @staticmethod
    def cli_channels(args) -> dict:
        """Role -> channel name of the ``--<role>-channel`` flags (None: the default name)."""
        return {role: getattr(args, f"{role}_channel", None) for role in ROLES
                if getattr(args, f"{role}_channel", None) is not None}

    @property
    def tip_plane_strain_compliance(self) -> float:
        """:math:`(1-\\nu_t^2)/E_t` in 1/Pa."""
        return (1.0 - self.tip_poisson ** 2) / self.tip_modulus


def check_poisson(value, name: str) -> float:
    """A Poisson ratio: a finite number in (-1, 0.5] (raises :class:`MaterialMapError`)."""
    try:
        v = math.nan if isinstance(value, bool) else float(value)
    except (TypeError, ValueError):
        v = math.nan
    if not -1.0 < v <= 0.5:  # NaN fails too
        raise MaterialMapError(f"{name} must be in (-1, 0.5] (got {value!r}); it is a Poisson ratio")
    return v


def _number_type(unit: str, minimum: float, maximum: float | None = None):
    """An argparse type: a finite number > ``minimum`` (and <= ``maximum``) in ``unit``."""
    import argparse

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be a number{' in ' + unit if unit else ''} (got {text!r})") from None
        if not (math.isfinite(value) and value > minimum and (maximum is None or value <= maximum)):
            rule = f"> {minimum:g}" + (f" and <= {maximum:g}" if maximum is not None else "")
            raise argparse.ArgumentTypeError(f"must be finite and {rule}{' ' + unit if unit else ''} (got {text})")
        return value
    return parse


def channel_to_si(values: np.ndarray, unit: str, quantity: str, conv: MaterialConversion,
                  channel: str = "") -> tuple[np.ndarray, str, dict]:
    """A mechanical channel in SI: ``(values, unit, how)``; refuses a unit without a stated conversion.

    ``quantity``: ``"modulus"`` (Pa), ``"adhesion"`` (N), ``"deformation"`` (m) or
    ``"dissipation"`` (J). ``how`` names the conversion applied (for the record). The viewer's
    deformation and dissipation maps keep the channel's unit when no scale is given.

    Examples
    --------
    >>> conv = MaterialConversion(5e-9, deflection_sensitivity=50e-9, spring_constant=40.0)
    >>> v, unit, how = channel_to_si(np.array([1e-3]), "V", "adhesion", conv)
    >>> float(v[0]), unit, how["factor"]
    (2e-09, 'N', 2e-06)
    """
    unit = (unit or "").strip()
    name = f"channel {channel!r}" if channel else f"the {quantity} channel"
    arr = np.asarray(values, dtype=np.float64)
    if quantity == "modulus":
        if unit == "Pa":
            return arr, "Pa", {"factor": 1.0, "from": "Pa"}
        if conv.modulus_scale is None:
            raise MaterialMapError(
                f"{name} is in {unit or 'no unit'!r}, not Pa: the file does not calibrate it, and arsurf will not "
                "read it as pascals; state its scale (modulus_scale in Pa per channel unit; CLI --modulus-scale)")
        return arr * conv.modulus_scale, "Pa", {"factor": conv.modulus_scale, "from": unit}
    if quantity == "adhesion":
        if unit == "N":
            return arr, "N", {"factor": 1.0, "from": "N"}
        if unit == "V":
            if conv.deflection_sensitivity is None or conv.spring_constant is None:
                raise MaterialMapError(
                    f"{name} is in volts of photodiode deflection: a force needs the deflection sensitivity (m/V) "
                    "and the spring constant (N/m) of the lever, F = V x S x k (CLI --deflection-sensitivity-nm-per-v, "
                    "--spring-constant); the file does not state them")
            f = conv.deflection_sensitivity * conv.spring_constant
            return arr * f, "N", {"factor": f, "from": "V"}
        if unit == "m":
            if conv.spring_constant is None:
                raise MaterialMapError(f"{name} is a deflection in metres: a force needs the spring constant (N/m; "
                                       "CLI --spring-constant)")
            return arr * conv.spring_constant, "N", {"factor": conv.spring_constant, "from": "m"}
        if conv.adhesion_scale is None:
            raise MaterialMapError(
                f"{name} is in {unit or 'no unit'!r}, not N: the file does not calibrate it, and arsurf will not read "
                "it as newtons; state its scale (adhesion_scale in N per channel unit; CLI --adhesion-scale)")
        return arr * conv.adhesion_scale, "N", {"factor": conv.adhesion_scale, "from": unit}
    if quantity in ("deformation", "dissipation"):
        si, scale = ("m", conv.deformation_scale) if quantity == "deformation" else ("J", conv.dissipation_scale)
        if unit == si:
            return arr, si, {"factor": 1.0, "from": si}
        if scale is None:
            return arr, unit or "arb", {"factor": 1.0, "from": unit, "note": f"no {quantity}_scale: channel units"}
        return arr * scale, si, {"factor": scale, "from": unit}
    raise MaterialMapError(f"unknown quantity {quantity!r}; one of modulus, adhesion, deformation, dissipation")


def reduced_modulus(sample_modulus, conv: MaterialConversion):
    r"""Contact modulus :math:`E^*` (Pa) of the tip on a sample of Young modulus :math:`E_s` (Pa).

    ``probe="same"`` (the rigid-tip DMT fit's own E*, for the probe that measured it) and
    ``probe="other"`` (the sample under another tip, Johnson Eq. 4.22):

    .. math:: E^* = \frac{E_s}{1-\nu_s^2}, \qquad
              E^* = \left(\frac{1-\nu_s^2}{E_s} + \frac{1-\nu_t^2}{E_t}\right)^{-1}

    ``sample_poisson`` None is read as :data:`DEFAULT_SAMPLE_POISSON` (a map resolves it from the
    file's header first: :meth:`MaterialConversion.with_sample_poisson`).

    Examples
    --------
    >>> round(float(reduced_modulus(3.4e9, MaterialConversion(10e-9))) / 1e9, 4)    # nu 0.3: 3.4 / 0.91
    3.7363
    >>> round(float(reduced_modulus(3.4e9, MaterialConversion(10e-9, probe="other"))) / 1e9, 4)  # + a Si tip
    3.6399
    """
    e = np.asarray(sample_modulus, dtype=np.float64)
    nu = DEFAULT_SAMPLE_POISSON if conv.sample_poisson is None else conv.sample_poisson
    if conv.probe == "same":
        return e / (1.0 - nu ** 2)
    return 1.0 / ((1.0 - nu ** 2) / e + conv.tip_plane_strain_compliance)


_TABLE: tuple | None = None


def _pull_off_table():
    """(ln lambda nodes, P_c) on a fine grid: a cubic spline through the exact values at
    :data:`_TABLE_PER_UNIT` nodes per unit, sampled every 1/:data:`_FINE_PER_UNIT` for linear
    interpolation (built once, ~0.1 s)."""
    global _TABLE
    if _TABLE is None:
        from scipy.interpolate import CubicSpline

        from arsurf.contact.maugis_dugdale import md_critical_point_kernel

        lo, hi = (math.log(x) for x in _LAM_LIMITS)
        x = np.linspace(lo, hi, int(round((hi - lo) * _TABLE_PER_UNIT)) + 1)
        p = np.array([md_critical_point_kernel(math.exp(v), 1)[1] for v in x])
        fine = np.linspace(lo, hi, int(round((hi - lo) * _FINE_PER_UNIT)) + 1)
        _TABLE = (fine, CubicSpline(x, p)(fine))
    return _TABLE


def pull_off_bar(lam):
    r"""Maugis-Dugdale pull-off load :math:`\bar P_c(\lambda) = P_c/\pi w R` (-2 DMT ... -1.5 JKR).

    From the table over :math:`\lambda \in [10^{-6}, 10^6]` (module docstring); outside it the DMT
    or JKR limit.

    Examples
    --------
    >>> round(float(pull_off_bar(1.0)), 6)
    -1.600735
    """
    x, p = _pull_off_table()
    pos = (np.log(np.asarray(lam, dtype=np.float64)) - x[0]) * ((x.size - 1) / (x[-1] - x[0]))
    i = np.clip(pos.astype(np.int64), 0, x.size - 2)  # the grid is uniform: the cell is found in O(1)
    f = pos - i
    out = p[i] + f * (p[i + 1] - p[i])
    out = np.where(pos < 0.0, -2.0, np.where(pos > x.size - 1, -1.5, out))
    return out if np.ndim(out) else float(out)


def work_of_adhesion_from_pull_off(force, reduced, conv: MaterialConversion):
    """Work of adhesion w (J/m^2) from pull-off forces (N, > 0) at the local reduced moduli (Pa).

    DMT :math:`w = F/2\\pi R`, JKR :math:`w = F/1.5\\pi R`, Maugis-Dugdale the fixed point of the
    module docstring. Arrays broadcast; a scalar in, a scalar out.

    Examples
    --------
    >>> from arsurf.contact.maugis_dugdale import MaugisDugdale
    >>> conv = MaterialConversion(tip_radius=20e-9)
    >>> md = MaugisDugdale(20e-9, 10e9, 0.08, 0.08 / conv.dugdale_range)
    >>> round(float(work_of_adhesion_from_pull_off(-md.pull_off_force(), 10e9, conv)), 9)
    0.08
    """
    f = np.asarray(force, dtype=np.float64)
    e = np.broadcast_to(np.asarray(reduced, dtype=np.float64), f.shape) if f.ndim else np.asarray(reduced, float)
    R = conv.tip_radius
    if conv.regime == "dmt":
        w = f / (2.0 * math.pi * R)
    elif conv.regime == "jkr":
        w = f / (1.5 * math.pi * R)
    else:
        k = 4.0 * e / 3.0
        geo = np.atleast_1d((2.0 / conv.dugdale_range) * np.cbrt(R / (math.pi * k * k))).ravel()
        ff = np.atleast_1d(f).ravel()
        w = ff / (2.0 * math.pi * R)
        todo = np.arange(w.size)
        for _ in range(60):  # each pass iterates only the pixels not yet converged
            lam = geo[todo] * np.cbrt(w[todo] ** 2)
            w_new = ff[todo] / (-pull_off_bar(lam) * math.pi * R)
            moving = np.abs(w_new - w[todo]) > 1e-14 * np.abs(w_new)
            w[todo] = w_new
            todo = todo[moving]
            if todo.size == 0:
                break
        w = w.reshape(f.shape)
    return w if np.ndim(w) else float(w)
