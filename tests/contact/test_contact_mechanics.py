"""Hertz, DMT and JKR: analytic values, critical points, the common interface, bad input."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import brentq

from arsurf.contact.materials import MATERIALS, effective_modulus, work_of_adhesion
from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.contact.mechanics import (
    DMT,
    JKR,
    ContactModel,
    ContactState,
    Hertz,
    jkr_radius_from_depth_kernel,
)
from arsurf.errors import ContactError

R = 20e-9
E_STAR = 50e9
W = 0.1


def all_models():
    return [Hertz(R, E_STAR), DMT(R, E_STAR, W), JKR(R, E_STAR, W), MaugisDugdale(R, E_STAR, W, 2e9)]


# ---------------------------------------------------------------------------------------------
# Hertz
# ---------------------------------------------------------------------------------------------

def test_hertz_analytic():
    h = Hertz(R, E_STAR)
    for d in [1e-12, 1e-10, 2e-9]:
        assert h.contact_radius(depth=d) == pytest.approx(math.sqrt(R * d), rel=1e-15)
        assert h.load(d) == pytest.approx(4.0 / 3.0 * E_STAR * math.sqrt(R) * d ** 1.5, rel=1e-14)
        P = h.load(d)
        assert h.depth(P) == pytest.approx(d, rel=1e-12)
        assert h.contact_radius(load=P) == pytest.approx(math.sqrt(R * d), rel=1e-12)
    st_ = h.contact_state(depth=-1e-9)
    assert (st_.radius, st_.load, st_.in_contact, st_.branch) == (0.0, 0.0, False, "separated")
    assert h.pull_off_force() == h.jump_in_depth() == h.jump_out_depth() == 0.0
    with pytest.raises(ContactError, match="below the pull-off force"):
        h.depth(-1e-9)


# ---------------------------------------------------------------------------------------------
# DMT
# ---------------------------------------------------------------------------------------------

def test_dmt_analytic():
    m = DMT(R, E_STAR, W)
    Pc = -2.0 * math.pi * W * R
    assert m.pull_off_force() == pytest.approx(Pc, rel=1e-15)
    for d in [0.0, 1e-10, 2e-9]:
        a = math.sqrt(R * d)
        assert m.contact_radius(depth=d) == pytest.approx(a, rel=1e-15, abs=0.0)
        assert m.load(d) == pytest.approx(4 * E_STAR * a ** 3 / (3 * R) + Pc, rel=1e-13)
    assert m.contact_radius(load=Pc) == 0.0
    assert m.depth(Pc) == 0.0
    assert m.depth(m.load(1e-9)) == pytest.approx(1e-9, rel=1e-12)
    # at contact (d = 0) the full adhesive force acts; for a gap DMT has no interaction
    assert m.contact_state(depth=0.0).in_contact and m.load(0.0) == pytest.approx(Pc)
    assert m.load(-1e-12) == 0.0 and m.contact_state(depth=-1e-12).branch == "separated"


# ---------------------------------------------------------------------------------------------
# JKR
# ---------------------------------------------------------------------------------------------

def jkr_reference_radius(delta, R=R, E=E_STAR, w=W):
    """Stable JKR radius from delta = a^2/R - sqrt(2 pi w a / E*), plain brentq from the fold up."""
    f = lambda a: a * a / R - math.sqrt(2 * math.pi * w * a / E) - delta   # noqa: E731
    a_fold = (math.pi * w * R * R / (8 * E)) ** (1 / 3)
    return brentq(f, a_fold, 1e-3, xtol=1e-22, rtol=1e-15)


def test_jkr_critical_points_analytic():
    j = JKR(R, E_STAR, W)
    piwR = math.pi * W * R
    assert j.pull_off_force() == pytest.approx(-1.5 * piwR, rel=1e-15)
    a_pull = (9 * math.pi * W * R * R / (8 * E_STAR)) ** (1 / 3)
    assert j.contact_radius(load=j.pull_off_force()) == pytest.approx(a_pull, rel=1e-12)
    a0 = (9 * math.pi * W * R * R / (2 * E_STAR)) ** (1 / 3)       # zero-load radius
    assert j.contact_radius(load=0.0) == pytest.approx(a0, rel=1e-12)
    # displacement control: fold at delta_c = -3/4 (pi^2 w^2 R / E*^2)^(1/3), load -5/6 pi w R
    d_c = -0.75 * (math.pi ** 2 * W ** 2 * R / E_STAR ** 2) ** (1 / 3)
    assert j.jump_out_depth() == pytest.approx(d_c, rel=1e-12)
    at_fold = j.contact_state(depth=d_c)
    assert at_fold.radius == pytest.approx((math.pi * W * R * R / (8 * E_STAR)) ** (1 / 3), rel=1e-6)
    assert at_fold.load == pytest.approx(-5.0 / 6.0 * piwR, rel=1e-6)
    assert j.contact_state(depth=d_c * (1 + 1e-9)).branch == "separated"
    # approaching, contact forms at delta = 0 with a = (2 pi w R^2 / E*)^(1/3) and P = -4/3 pi w R
    assert j.jump_in_depth() == 0.0
    snap = j.contact_state(depth=0.0, approach=True)
    assert snap.radius == pytest.approx((2 * math.pi * W * R * R / E_STAR) ** (1 / 3), rel=1e-12)
    assert snap.load == pytest.approx(-4.0 / 3.0 * piwR, rel=1e-12)
    assert j.contact_state(depth=0.5 * d_c, approach=True).branch == "separated"
    assert j.contact_state(depth=0.5 * d_c).branch == "contact"


def test_jkr_kernel_against_reference():
    j = JKR(R, E_STAR, W)
    for d in np.concatenate([j.jump_out_depth() * np.array([0.999999, 0.99, 0.5]), np.geomspace(1e-12, 1e-8, 9)]):
        a = j.contact_radius(depth=d)
        assert a == pytest.approx(jkr_reference_radius(d), rel=1e-9)
        # dimensional JKR relations hold for the returned state
        P = j.load(d)
        assert P == pytest.approx(4 * E_STAR * a ** 3 / (3 * R) - math.sqrt(8 * math.pi * W * E_STAR * a ** 3),
                                  rel=1e-9, abs=1e-9 * math.pi * W * R)
    assert jkr_radius_from_depth_kernel(math.nan)[0] == -1
    assert jkr_radius_from_depth_kernel(-10.0) == (2, 0.0)


def test_jkr_equilibria():
    j = JKR(R, E_STAR, W)
    d = 0.5 * j.jump_out_depth()
    eqs = j.equilibria(depth=d)
    assert [(e.branch, e.stable) for e in eqs] == [("contact", True), ("contact", False), ("separated", True)]
    for e in eqs[:2]:
        assert e.radius ** 2 / R - math.sqrt(2 * math.pi * W * e.radius / E_STAR) == pytest.approx(d, rel=1e-9)
    eqs = j.equilibria(load=0.5 * j.pull_off_force())
    assert [e.stable for e in eqs] == [True, False]
    assert eqs[0].radius > j.contact_radius(load=j.pull_off_force()) > eqs[1].radius


def test_jkr_zero_adhesion_is_hertz():
    j, h = JKR(R, E_STAR, 0.0), Hertz(R, E_STAR)
    for d in [1e-10, 1e-9]:
        assert j.contact_radius(depth=d) == h.contact_radius(depth=d)
        assert j.load(d) == h.load(d)
    assert j.pull_off_force() == 0.0 and j.jump_out_depth() == 0.0


def test_jkr_adhesion_package_oracle():
    AJ = pytest.importorskip("Adhesion.ReferenceSolutions.JKR")
    j = JKR(R, E_STAR, W)
    for a in np.array([0.3, 1.0, 3.0]) * j.radius_scale:
        P = AJ.force(contact_radius=a, radius=R, contact_modulus=E_STAR, work_of_adhesion=W)
        d = AJ.penetration(contact_radius=a, radius=R, contact_modulus=E_STAR, work_of_adhesion=W)
        if d >= j.jump_out_depth() and a >= 6 ** (-1 / 3) * j.radius_scale:
            assert j.contact_radius(depth=d) == pytest.approx(a, rel=1e-9)
            assert j.load(d) == pytest.approx(P, rel=1e-9)


# ---------------------------------------------------------------------------------------------
# the common interface
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("model", all_models(), ids=lambda m: type(m).__name__)
def test_common_interface(model):
    assert isinstance(model, ContactModel)
    assert model.K == pytest.approx(4 * E_STAR / 3)
    d = np.array([[-5e-9, 0.5e-9], [1e-9, 2e-9]])
    a = model.contact_radius(depth=d)
    p = model.load(d)
    assert a.shape == d.shape and p.shape == d.shape
    assert isinstance(model.contact_radius(depth=1e-9), float)
    assert isinstance(model.load(1e-9), float)
    assert a[0, 0] == 0.0 and p[0, 0] == 0.0                       # far away: nothing
    assert np.all(np.diff(a[1]) > 0) and np.all(np.diff(p[1]) > 0)  # deeper: larger, harder
    st_ = model.contact_state(depth=1e-9)
    assert isinstance(st_, ContactState) and st_.in_contact and st_.stable and st_.branch == "contact"
    # load control inverts displacement control on the load-stable branch
    P = model.load(2e-9)
    assert model.depth(P) == pytest.approx(2e-9, rel=1e-8)
    assert model.contact_radius(load=P) == pytest.approx(model.contact_radius(depth=2e-9), rel=1e-8)
    assert model.pull_off_force() <= 0.0
    assert model.jump_out_depth() <= model.jump_in_depth() <= 0.0
    arr = model.contact_state(depth=d)
    assert arr.branch.shape == d.shape and arr.in_contact.dtype == bool
    with pytest.raises(ContactError, match="`depth` must be finite"):
        model.load(math.nan)
    with pytest.raises(ContactError, match="`load` must be finite"):
        model.contact_radius(load=[0.0, math.nan])
    with pytest.raises(ContactError, match="exactly one of"):
        model.contact_radius(depth=1e-9, load=1e-9)
    with pytest.raises(ContactError, match="one scalar"):
        model.equilibria(depth=[1e-9, 2e-9])


@pytest.mark.parametrize("cls", [Hertz, DMT, JKR, MaugisDugdale])
def test_bad_parameters(cls):
    extra = () if cls is Hertz else (W,)
    with pytest.raises(ContactError, match=r"tip_radius must be positive and finite \(got -1e-08 m\)"):
        cls(-10e-9, E_STAR, *extra)
    with pytest.raises(ContactError, match="effective_modulus must be positive.*E\\*"):
        cls(R, 0.0, *extra)
    with pytest.raises(ContactError, match="tip_radius must be a number"):
        cls("big", E_STAR, *extra)
    if cls is not Hertz:
        with pytest.raises(ContactError, match=r"work_of_adhesion must be >= 0 and finite \(got -0.1"):
            cls(R, E_STAR, -0.1)


def test_from_materials():
    tip, sample = MATERIALS["Si3N4"], MATERIALS["mica"]
    j = JKR.from_materials(20e-9, tip, sample)
    assert j.effective_modulus == effective_modulus(tip, sample)
    assert j.work_of_adhesion == work_of_adhesion(tip, sample)
    h = Hertz.from_materials(20e-9, "Si", "Au")
    assert h.effective_modulus == effective_modulus("Si", "Au")
    md = MaugisDugdale.from_materials(20e-9, "Si", "polystyrene", dugdale_stress=1e8)
    assert md.dugdale_stress == 1e8


# ---------------------------------------------------------------------------------------------
# properties
# ---------------------------------------------------------------------------------------------

@settings(max_examples=60, deadline=None)
@given(which=st.sampled_from(["Hertz", "DMT", "JKR"]), log_d=st.floats(-12.0, -7.5),
       log_w=st.floats(-3.0, 0.0), log_e=st.floats(9.0, 11.5))
def test_round_trip_depth_load(which, log_d, log_w, log_e):
    E, w, d = 10.0 ** log_e, 10.0 ** log_w, 10.0 ** log_d
    model = {"Hertz": lambda: Hertz(R, E), "DMT": lambda: DMT(R, E, w), "JKR": lambda: JKR(R, E, w)}[which]()
    a = model.contact_radius(depth=d)
    P = model.load(d)
    if P >= model.pull_off_force() and (which != "JKR" or a >= model.contact_radius(load=model.pull_off_force())):
        assert model.depth(P) == pytest.approx(d, rel=1e-7)
        assert model.contact_radius(load=P) == pytest.approx(a, rel=1e-7)
