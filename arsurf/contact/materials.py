"""Tip and sample materials: elastic constants, surface energies, and how they combine.

* :class:`Material` - Young's modulus, Poisson ratio, surface energy, and where each came from.
* :data:`MATERIALS` - presets for the tips and samples of AFM nanomanipulation (Si, Si3N4, Au,
  mica, HOPG, polystyrene, PMMA, polycarbonate, MWCNT). **This table is the one place where
  default material values live**; each carries its source.
* :func:`effective_modulus` - the contact modulus
  :math:`1/E^* = (1-\\nu_1^2)/E_1 + (1-\\nu_2^2)/E_2` (the convention of every contact model in
  arsurf; :math:`K = 4E^*/3` is the other one in the literature).
* :func:`work_of_adhesion` - Dupré work of adhesion from surface energies (Berthelot /
  Girifalco-Good geometric mean :math:`w = 2\\sqrt{\\gamma_1\\gamma_2}`) and
  :func:`work_of_adhesion_hamaker` from a Hamaker constant (:math:`w = A/12\\pi D_0^2`).
* :func:`default_dugdale_stress` - :math:`\\sigma_0 = 16w/(9\\sqrt3 z_0)`, the peak stress of the
  Lennard-Jones surface law with the same *w* and equilibrium spacing :math:`z_0`.

How good are these numbers? Elastic constants of bulk crystals and polymers are known to a few
per cent; thin films, tip apexes and nanotubes much less well (see the notes). Surface energies
in an AFM depend on oxide, contamination and humidity far more than on the bulk material; where
a measured surface energy exists it is used, otherwise the dispersion (Lifshitz-van der Waals)
value :math:`\\gamma = A/24\\pi D_0^2` from the Hamaker constant, which is what a clean dry contact
retains. Measure *w* (pull-off force) for quantitative work and pass it explicitly.

Examples
--------
>>> from arsurf.contact.materials import MATERIALS, effective_modulus, work_of_adhesion
>>> tip, sample = MATERIALS["Si"], MATERIALS["polystyrene"]
>>> round(effective_modulus(tip, sample) / 1e9, 3)
3.742
>>> round(work_of_adhesion(tip, sample), 4)
0.0718
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType

from arsurf.errors import ContactError

__all__ = [
    "DEFAULT_EQUILIBRIUM_SPACING",
    "HAMAKER_CUTOFF",
    "MATERIALS",
    "Material",
    "default_dugdale_stress",
    "effective_modulus",
    "surface_energy_from_hamaker",
    "work_of_adhesion",
    "work_of_adhesion_hamaker",
]

#: Israelachvili's "universal" cut-off distance D0 = 0.165 nm: with it, gamma = A / (24 pi D0^2)
#: reproduces measured surface energies of non-hydrogen-bonding solids to ~10-20 %
#: (J. N. Israelachvili, Intermolecular and Surface Forces, 3rd ed., Academic Press 2011, §13.5).
HAMAKER_CUTOFF = 0.165e-9

#: Equilibrium spacing z0 of the Lennard-Jones surface law used for the default Dugdale stress:
#: a typical interatomic distance, 0.3 nm (Johnson & Greenwood, J. Colloid Interface Sci. 192,
#: 326 (1997), use z0 of this size; Maugis 1992 matches the Dugdale range h0 = 0.97 z0).
DEFAULT_EQUILIBRIUM_SPACING = 0.3e-9


@dataclass(frozen=True)
class Material:
    """Elastic and surface properties of a tip or sample material (SI units).

    Parameters
    ----------
    name : str
    youngs_modulus : float, pascals
        Young's modulus E (for anisotropic solids: the value for indentation normal to the
        usual surface, see ``source``).
    poisson_ratio : float
        Poisson's ratio, in (-1, 0.5].
    surface_energy : float or None, J/m^2
        Surface free energy gamma used for the work of adhesion; None when unknown.
    source : str
        Where the numbers come from (handbook, paper).
    """

    name: str
    youngs_modulus: float
    poisson_ratio: float
    surface_energy: float | None = None
    source: str = ""

    def __post_init__(self) -> None:
        E = float(self.youngs_modulus)
        nu = float(self.poisson_ratio)
        if not (math.isfinite(E) and E > 0.0):
            raise ContactError(
                f"Material {self.name!r}: youngs_modulus must be positive and finite (got {E!r} Pa); "
                "give Young's modulus in pascals (e.g. 169e9 for silicon)"
            )
        if not (math.isfinite(nu) and -1.0 < nu <= 0.5):
            raise ContactError(
                f"Material {self.name!r}: poisson_ratio must lie in (-1, 0.5] (got {nu!r}); "
                "isotropic elasticity allows no other values"
            )
        if self.surface_energy is not None:
            g = float(self.surface_energy)
            if not (math.isfinite(g) and g >= 0.0):
                raise ContactError(
                    f"Material {self.name!r}: surface_energy must be >= 0 and finite (got {g!r} J/m^2), "
                    "or None when unknown"
                )
            object.__setattr__(self, "surface_energy", g)
        object.__setattr__(self, "youngs_modulus", E)
        object.__setattr__(self, "poisson_ratio", nu)

    @property
    def plane_strain_modulus(self) -> float:
        """:math:`E/(1-\\nu^2)` in pascals."""
        return self.youngs_modulus / (1.0 - self.poisson_ratio ** 2)


def surface_energy_from_hamaker(hamaker: float, cutoff: float = HAMAKER_CUTOFF) -> float:
    """Dispersion surface energy :math:`\\gamma = A/(24\\pi D_0^2)` in J/m^2.

    Parameters
    ----------
    hamaker : float, joules
        Hamaker constant A11 of the material across vacuum.
    cutoff : float, metres
        D0, default :data:`HAMAKER_CUTOFF` (0.165 nm).

    Source: Israelachvili, Intermolecular and Surface Forces (3rd ed.), Eq. 13.16 and §13.5.

    Examples
    --------
    >>> round(surface_energy_from_hamaker(6.5e-20), 4)    # polystyrene: measured ~0.033 (dispersive)
    0.0317
    """
    A = float(hamaker)
    D0 = float(cutoff)
    if not (math.isfinite(A) and A > 0.0):
        raise ContactError(f"`hamaker` must be a positive Hamaker constant in joules (got {A!r}); typical 1e-20..5e-19 J")
    if not (math.isfinite(D0) and D0 > 0.0):
        raise ContactError(f"`cutoff` must be a positive distance in metres (got {D0!r}); Israelachvili's is 0.165e-9")
    return A / (24.0 * math.pi * D0 * D0)


# ---------------------------------------------------------------------------------------------
# THE preset table (the one place where default material values live)
# ---------------------------------------------------------------------------------------------
# Hamaker constants (A11 across vacuum) used for dispersion surface energies, with sources:
_A_SIO2 = 6.5e-20    # amorphous SiO2 (native oxide on Si tips): L. Bergström, Adv. Colloid Interface Sci. 70, 125 (1997)
_A_SI3N4 = 16.7e-20  # amorphous Si3N4: R. H. French, J. Am. Ceram. Soc. 83, 2117 (2000)
_A_AU = 40e-20       # gold (upper end of 25-40e-20 J for Au/Ag/Cu): Israelachvili (2011) Table 13.2
_A_MICA = 10e-20     # muscovite mica: Israelachvili (2011) Table 13.2

_PRESETS = (
    Material(
        "Si", 130e9, 0.28, surface_energy_from_hamaker(_A_SIO2),
        # AFM tips are etched from (100) wafers: the apex is loaded along [100], E[100] = 130 GPa,
        # nu(100 plane, [100]/[010]) = 0.28; surface = native oxide (dispersion value, 0.032 J/m^2).
        "E, nu: M. A. Hopcroft, W. D. Nix, T. W. Kenny, J. Microelectromech. Syst. 19, 229 (2010), "
        "[100] direction; gamma: native SiO2, Hamaker 6.5e-20 J (Bergstrom 1997) with D0 = 0.165 nm",
    ),
    Material(
        "Si3N4", 222e9, 0.28, surface_energy_from_hamaker(_A_SI3N4),
        # LPCVD silicon nitride film (the material of nitride AFM tips), bulge test.
        "E, nu: J. J. Vlassak, W. D. Nix, J. Mater. Res. 7, 3242 (1992), LPCVD SiNx film; "
        "gamma: Hamaker 16.7e-20 J (R. H. French, J. Am. Ceram. Soc. 83, 2117 (2000)) with D0 = 0.165 nm",
    ),
    Material(
        "Au", 78e9, 0.44, surface_energy_from_hamaker(_A_AU),
        # polycrystalline gold; clean-metal surface energy (~1.5 J/m^2) is never seen in air, the
        # dispersion value (0.195 J/m^2) is the relevant order for a contaminated, dry contact.
        "E, nu: CRC Handbook of Chemistry and Physics, elastic constants of polycrystalline metals; "
        "gamma: Hamaker 40e-20 J (Israelachvili 2011, Table 13.2) with D0 = 0.165 nm",
    ),
    Material(
        "mica", 61e9, 0.25, surface_energy_from_hamaker(_A_MICA),
        # muscovite is strongly anisotropic; for indentation normal to the cleavage plane the
        # c-axis stiffness c33 = 61 GPa is used as an isotropic stand-in (nu typical of silicates).
        "E: c33 of muscovite, L. E. McNeil, M. Grimsditch, J. Phys.: Condens. Matter 5, 1681 (1993); "
        "nu: 0.25 assumed; gamma: Hamaker 10e-20 J (Israelachvili 2011, Table 13.2) with D0 = 0.165 nm",
    ),
    Material(
        "HOPG", 36.5e9, 0.16, 0.135,
        # indentation of the basal plane loads the c axis: C33 = 36.5 GPa; nu = in-plane 0.16;
        # gamma = half the measured interlayer binding energy 0.27 J/m^2.
        "E: C33, O. L. Blakslee et al., J. Appl. Phys. 41, 3373 (1970); nu: in-plane value, same source; "
        "gamma: half the interlayer binding energy 0.27 J/m^2, Z. Liu et al., Phys. Rev. B 85, 205418 (2012)",
    ),
    Material(
        "polystyrene", 3.4e9, 0.34, 0.0407,
        "E, nu: J. E. Mark (ed.), Physical Properties of Polymers Handbook, 2nd ed., Springer (2007); "
        "gamma at 20 C: S. Wu, Polymer Interface and Adhesion, Marcel Dekker (1982)",
    ),
    Material(
        "PMMA", 3.0e9, 0.37, 0.0411,
        "E, nu: J. E. Mark (ed.), Physical Properties of Polymers Handbook, 2nd ed., Springer (2007) "
        "(2.4-3.3 GPa, 0.35-0.40); gamma at 20 C: S. Wu, Polymer Interface and Adhesion (1982)",
    ),
    Material(
        "polycarbonate", 2.2e9, 0.37, 0.043,
        # bisphenol-A polycarbonate; surface energies in compilations spread ~35-46 mJ/m^2 with method.
        "E, nu: 2.0-2.4 GPa, 0.37, Polymer Handbook (Brandrup, Immergut, Grulke, 4th ed., Wiley 1999); "
        "gamma: ~0.043 J/m^2, S. Wu, Polymer Interface and Adhesion (1982) (method-dependent, +-5 mJ/m^2)",
    ),
    Material(
        "MWCNT", 1.28e12, 0.16, 0.135,
        # axial modulus from AFM bending of MWCNTs; a tip pressing on a tube side probes the far
        # softer radial stiffness (tens of GPa or less): pass a measured radial modulus for dents.
        "E: axial, E. W. Wong, P. E. Sheehan, C. M. Lieber, Science 277, 1971 (1997); nu: graphite "
        "in-plane (Blakslee 1970); gamma: graphitic wall as HOPG (Liu et al. 2012)",
    ),
)

#: Preset materials by name (read-only). Each entry's ``source`` names the handbook or paper.
MATERIALS: MappingProxyType[str, Material] = MappingProxyType({m.name: m for m in _PRESETS})


def _material(x, role: str) -> Material:
    if isinstance(x, Material):
        return x
    if isinstance(x, str):
        try:
            return MATERIALS[x]
        except KeyError:
            raise ContactError(
                f"unknown {role} material {x!r}; presets are {sorted(MATERIALS)}, or pass a Material(...)"
            ) from None
    raise ContactError(f"{role} must be a Material or a preset name (got {type(x).__name__})")


def effective_modulus(tip, sample) -> float:
    """Contact modulus :math:`E^*` of two elastic bodies, in pascals.

    .. math:: \\frac{1}{E^*} = \\frac{1-\\nu_1^2}{E_1} + \\frac{1-\\nu_2^2}{E_2}

    This is the :math:`E^*` every arsurf contact model takes (Johnson, *Contact Mechanics* Eq.
    4.22); Maugis and Johnson-Greenwood write :math:`K = 4E^*/3`.

    Parameters
    ----------
    tip, sample : Material or str
        Materials or preset names from :data:`MATERIALS`.

    Examples
    --------
    >>> round(effective_modulus("Si3N4", "mica") / 1e9, 2)
    51.23
    """
    a = _material(tip, "tip")
    b = _material(sample, "sample")
    return 1.0 / (1.0 / a.plane_strain_modulus + 1.0 / b.plane_strain_modulus)


def work_of_adhesion(tip, sample) -> float:
    """Dupré work of adhesion :math:`w = 2\\sqrt{\\gamma_1\\gamma_2}` in J/m^2.

    The geometric-mean (Berthelot / Girifalco-Good with interaction parameter 1) combining rule,
    exact for dispersion forces and consistent with :math:`A_{12} = \\sqrt{A_{11}A_{22}}`
    (Israelachvili 2011, §13.6). For identical materials it gives :math:`w = 2\\gamma`.

    Parameters
    ----------
    tip, sample : Material or str

    Raises
    ------
    ContactError
        If either material has no surface energy.

    Examples
    --------
    >>> round(work_of_adhesion("HOPG", "HOPG"), 3)
    0.27
    """
    a = _material(tip, "tip")
    b = _material(sample, "sample")
    for m in (a, b):
        if m.surface_energy is None:
            raise ContactError(
                f"material {m.name!r} has no surface_energy; give one (J/m^2) or pass work_of_adhesion explicitly"
            )
    return 2.0 * math.sqrt(a.surface_energy * b.surface_energy)


def work_of_adhesion_hamaker(hamaker: float, cutoff: float = HAMAKER_CUTOFF) -> float:
    """Work of adhesion :math:`w = A_{12}/(12\\pi D_0^2)` from a Hamaker constant, in J/m^2.

    Use the tip-sample Hamaker constant across the medium (vacuum/air: :math:`A_{12} \\approx
    \\sqrt{A_{11}A_{22}}`).

    Examples
    --------
    >>> round(work_of_adhesion_hamaker(6.5e-20), 4)
    0.0633
    """
    return 2.0 * surface_energy_from_hamaker(hamaker, cutoff)


def default_dugdale_stress(work_of_adhesion: float, spacing: float = DEFAULT_EQUILIBRIUM_SPACING) -> float:
    """Default Dugdale stress :math:`\\sigma_0 = \\frac{16 w}{9\\sqrt{3} z_0} \\approx 1.03\\,w/z_0`, in pascals.

    The Dugdale (constant-stress) law replaces the Lennard-Jones surface law; Maugis (1992) and
    Johnson & Greenwood (1997) match its stress to the LJ theoretical strength
    :math:`16w/(9\\sqrt3 z_0)`, so the range is :math:`h_0 = w/\\sigma_0 = 0.97 z_0`.

    Parameters
    ----------
    work_of_adhesion : float, J/m^2
    spacing : float, metres
        Equilibrium spacing :math:`z_0`; default :data:`DEFAULT_EQUILIBRIUM_SPACING` (0.3 nm).

    Examples
    --------
    >>> round(default_dugdale_stress(0.1) / 1e6, 1)    # MPa
    342.1
    """
    w = float(work_of_adhesion)
    z0 = float(spacing)
    if not (math.isfinite(w) and w > 0.0):
        raise ContactError(f"`work_of_adhesion` must be positive and finite (got {w!r} J/m^2) to set a Dugdale stress")
    if not (math.isfinite(z0) and z0 > 0.0):
        raise ContactError(f"`spacing` must be a positive distance in metres (got {z0!r}); typical 0.2e-9..0.4e-9")
    return 16.0 * w / (9.0 * math.sqrt(3.0) * z0)
