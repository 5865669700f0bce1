"""Material presets and the combining rules (E*, work of adhesion, Dugdale stress)."""
from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from arsurf.contact.materials import (
    DEFAULT_EQUILIBRIUM_SPACING,
    HAMAKER_CUTOFF,
    MATERIALS,
    Material,
    default_dugdale_stress,
    effective_modulus,
    surface_energy_from_hamaker,
    work_of_adhesion,
    work_of_adhesion_hamaker,
)
from arsurf.errors import ContactError

REQUIRED = ["Si", "Si3N4", "Au", "mica", "HOPG", "polystyrene", "PMMA", "polycarbonate", "MWCNT"]


def test_presets_complete_and_sourced():
    assert set(REQUIRED) <= set(MATERIALS)
    for name in REQUIRED:
        m = MATERIALS[name]
        assert m.name == name
        assert 1e8 < m.youngs_modulus < 2e12
        assert 0.0 < m.poisson_ratio < 0.5
        assert m.surface_energy is not None and 0.01 < m.surface_energy < 0.5   # J/m^2, AFM-relevant range
        assert len(m.source) > 20 and any(ch.isdigit() for ch in m.source)       # a named, dated source
    with pytest.raises(TypeError):
        MATERIALS["Si"] = Material("x", 1e9, 0.3)                                # read-only table


def test_preset_values_against_their_sources():
    assert MATERIALS["Si"].youngs_modulus == 130e9                 # Hopcroft 2010, E[100]
    assert MATERIALS["HOPG"].youngs_modulus == 36.5e9              # Blakslee 1970, C33
    assert MATERIALS["HOPG"].surface_energy == pytest.approx(0.27 / 2)   # Liu 2012 binding energy / 2
    assert MATERIALS["polystyrene"].surface_energy == pytest.approx(0.0407)   # Wu 1982
    # dispersion surface energies: gamma = A / (24 pi D0^2) with the named Hamaker constants
    assert MATERIALS["Si3N4"].surface_energy == pytest.approx(16.7e-20 / (24 * math.pi * HAMAKER_CUTOFF ** 2))
    assert MATERIALS["mica"].surface_energy == pytest.approx(0.0487, abs=1e-4)


def test_effective_modulus_formula():
    a = Material("a", 100e9, 0.3)
    b = Material("b", 10e9, 0.4)
    expected = 1.0 / ((1 - 0.3 ** 2) / 100e9 + (1 - 0.4 ** 2) / 10e9)
    assert effective_modulus(a, b) == pytest.approx(expected, rel=1e-15)
    # identical bodies: E* = E / (2 (1 - nu^2)); a rigid partner: E* -> E / (1 - nu^2)
    assert effective_modulus(a, a) == pytest.approx(100e9 / (2 * (1 - 0.09)), rel=1e-15)
    rigid = Material("rigid", 1e30, 0.0)
    assert effective_modulus(rigid, b) == pytest.approx(10e9 / (1 - 0.16), rel=1e-12)
    assert effective_modulus("Si", "PMMA") == effective_modulus(MATERIALS["Si"], MATERIALS["PMMA"])


@settings(max_examples=50, deadline=None)
@given(e1=st.floats(1e8, 1e12), e2=st.floats(1e8, 1e12), n1=st.floats(-0.9, 0.5), n2=st.floats(-0.9, 0.5))
def test_effective_modulus_symmetric_and_bounded(e1, e2, n1, n2):
    a, b = Material("a", e1, n1), Material("b", e2, n2)
    es = effective_modulus(a, b)
    assert es == pytest.approx(effective_modulus(b, a), rel=1e-14)
    assert es <= min(a.plane_strain_modulus, b.plane_strain_modulus) * (1 + 1e-14)   # softer body dominates
    assert es >= 0.5 * min(a.plane_strain_modulus, b.plane_strain_modulus) * (1 - 1e-14)


def test_work_of_adhesion_rules():
    assert work_of_adhesion("HOPG", "HOPG") == pytest.approx(0.27)            # w = 2 gamma for like bodies
    g1, g2 = MATERIALS["Si"].surface_energy, MATERIALS["Au"].surface_energy
    assert work_of_adhesion("Si", "Au") == pytest.approx(2 * math.sqrt(g1 * g2), rel=1e-15)
    # Hamaker route: w = A12 / (12 pi D0^2) = 2 gamma for like bodies
    assert work_of_adhesion_hamaker(6.5e-20) == pytest.approx(2 * surface_energy_from_hamaker(6.5e-20))
    assert surface_energy_from_hamaker(6.5e-20) == pytest.approx(0.0317, abs=1e-4)   # PS: measured ~0.033
    with pytest.raises(ContactError, match="has no surface_energy"):
        work_of_adhesion(Material("bare", 1e9, 0.3), "Si")


def test_default_dugdale_stress():
    w = 0.1
    s0 = default_dugdale_stress(w)
    assert s0 == pytest.approx(16 * w / (9 * math.sqrt(3) * DEFAULT_EQUILIBRIUM_SPACING), rel=1e-15)
    assert round(w / s0 / DEFAULT_EQUILIBRIUM_SPACING, 2) == 0.97     # h0 = 0.97 z0 (Maugis 1992)
    assert default_dugdale_stress(w, spacing=0.2e-9) == pytest.approx(1.5 * s0)


def test_bad_materials():
    with pytest.raises(ContactError, match=r"youngs_modulus must be positive.*got -1"):
        Material("x", -1.0, 0.3)
    with pytest.raises(ContactError, match=r"poisson_ratio must lie in \(-1, 0.5\]"):
        Material("x", 1e9, 0.7)
    with pytest.raises(ContactError, match="surface_energy must be >= 0"):
        Material("x", 1e9, 0.3, surface_energy=math.nan)
    with pytest.raises(ContactError, match="unknown tip material 'Diamond'; presets are"):
        effective_modulus("Diamond", "Si")
    with pytest.raises(ContactError, match="sample must be a Material"):
        effective_modulus("Si", 3.0)
    with pytest.raises(ContactError, match="work_of_adhesion` must be positive"):
        default_dugdale_stress(0.0)
    with pytest.raises(ContactError, match="hamaker"):
        surface_energy_from_hamaker(-1e-20)
