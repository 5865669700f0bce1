"""Calibration: [MWCNT] k_v/k_h, approach-curve S_n with contact detection and 95 % CI, wedge
G_l and mu, thermal-noise k, [Alabdulmuhsin] force-scaling tables, bad input."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate

from arsurf.errors import ForceError
from arsurf.force.calibration import (
    BOLTZMANN,
    OPTICAL_LEVER_FIRST_MODE,
    TRUE_DEFLECTION_FIRST_MODE,
    lateral_sensitivity_from_vertical,
    normal_sensitivity_from_curve,
    sho_psd,
    thermal_spring_constant,
    vertical_sensitivity_from_steps,
    wedge_calibration,
    wedge_from_slopes,
)
from arsurf.force.haptic_gains import signal_to_haptic_force_gain
from arsurf.force.simulate import (
    simulate_approach_curve,
    simulate_thermal_trace,
    simulate_wedge_sliding,
    wedge_forces,
)

# [MWCNT], sec. 2.3.1: grating steps and the vertical PSD jumps
STEPS = [20e-9, 101.8e-9, 500e-9]
JUMPS = [0.032, 0.156, 0.710]
# [Alabdulmuhsin]: k = 0.3 N/m, S_n = 1117 nm/V, G_l = -63.78 nN/V, mu = 1.861, K_f = 15e6
K_SEED001, SN_SEED001, GL_SEED001, MU_SEED001 = 0.3, 1117e-9, -63.78e-9, 1.861
NORMAL_GAIN = K_SEED001 * SN_SEED001  # N per vertical volt


# ---- [MWCNT]: k_v and k_h -----------------------------------------------------------------------
def test_seed000_vertical_sensitivity():
    r = vertical_sensitivity_from_steps(STEPS, JUMPS)
    assert r.value == pytest.approx(706e-9, rel=0.01)
    # reference: least squares through the origin by numpy
    h, s = np.array(STEPS), np.array(JUMPS)
    coef, res, *_ = np.linalg.lstsq(s[:, None], h, rcond=None)
    assert r.value == pytest.approx(coef[0], rel=1e-13)
    assert r.uncertainty == pytest.approx(math.sqrt(res[0] / 2 / (s @ s)), rel=1e-12)
    assert np.allclose(r.residuals, h - coef[0] * s, atol=1e-20)
    lo, hi = r.confidence_interval
    assert lo < 706e-9 < hi
    with_intercept = vertical_sensitivity_from_steps(STEPS, JUMPS, through_origin=False)
    assert with_intercept.value == pytest.approx(np.polyfit(s, h, 1)[0], rel=1e-12)
    assert with_intercept.value == pytest.approx(706e-9, rel=0.01)


def test_seed000_lateral_sensitivity():
    # [MWCNT]: k_h = k_v / l_c = 0.00565 rad/V; l_c follows from its two numbers
    l_c = 706e-9 / 0.00565
    assert lateral_sensitivity_from_vertical(706e-9, l_c, model="chord") == pytest.approx(0.00565, rel=1e-12)
    kv = vertical_sensitivity_from_steps(STEPS, JUMPS).value
    assert lateral_sensitivity_from_vertical(kv, l_c, model="chord") == pytest.approx(0.00565, rel=0.01)
    # the end-load slope of the calibrated deflection is 3/2 of the chord (the default: 0.00848 rad/V)
    assert lateral_sensitivity_from_vertical(706e-9, l_c) == pytest.approx(1.5 * 0.00565, rel=1e-12)


def test_the_default_lateral_sensitivity_is_the_photodiodes_bending_sensitivity():
    """Why k_h defaults to the end-load slope, not [MWCNT]'s chord: torsion and bending share
    one angular sensitivity (the seed's premise), and the bending one arsurf reads from the same
    deflection sensitivity is the end slope."""
    from arsurf.force.photodiode import Photodiode

    pd = Photodiode.from_deflection_sensitivity(706e-9, 125e-6)
    assert lateral_sensitivity_from_vertical(706e-9, 125e-6) == pytest.approx(pd.vertical_sensitivity, rel=1e-15)


# ---- approach curve --------------------------------------------------------------------------------
def brute_force_contact(z, s):
    """Slow reference: hinge least squares at every sample breakpoint with numpy.linalg.lstsq."""
    best, arg = np.inf, None
    for j in range(5, z.size - 5):
        a = np.column_stack([np.ones_like(z), np.maximum(z - z[j], 0.0)])
        r = s - a @ np.linalg.lstsq(a, s, rcond=None)[0]
        if r @ r < best:
            best, arg = r @ r, z[j]
    return arg


def test_approach_curve_contact_and_sensitivity():
    z, v = simulate_approach_curve(SN_SEED001, 150e-9, 0.0, 400e-9, 600, offset=0.02, noise=2e-3, seed=3)
    r = normal_sensitivity_from_curve(z, v)
    step = z[1] - z[0]
    assert abs(r.details["contact_point"] - 150e-9) < 3 * step
    assert abs(r.details["contact_point"] - brute_force_contact(z, v)) <= step
    lo, hi = r.confidence_interval
    assert lo < SN_SEED001 < hi
    assert abs(r.value - SN_SEED001) < 3 * r.uncertainty
    assert r.uncertainty / r.value < 0.01
    assert r.details["baseline"] == pytest.approx(0.02, abs=1e-3)
    assert r.residuals.size == r.details["n_fit"]
    assert np.std(r.residuals) == pytest.approx(2e-3, rel=0.15)


def test_approach_curve_confidence_interval_coverage():
    """The 95 % interval covers the true S_n in 95 +- 5 % of 120 independent noisy curves."""
    hits = 0
    for seed in range(120):
        z, v = simulate_approach_curve(SN_SEED001, 120e-9, 0.0, 300e-9, 300, noise=3e-3, seed=seed)
        lo, hi = normal_sensitivity_from_curve(z, v).confidence_interval
        hits += lo <= SN_SEED001 <= hi
    assert 0.89 <= hits / 120 <= 1.0


def test_approach_retract_cycle_and_negative_gain():
    # [Alabdulmuhsin] Eq. 13 has a negative sensitivity (-1117 nm/V); adhesion distorts the retract branch
    z, v = simulate_approach_curve(-SN_SEED001, 150e-9, 0.0, 400e-9, 500, noise=1e-3, retract=True,
                                   pull_off=60e-9, seed=9)
    r = normal_sensitivity_from_curve(z, v)
    assert r.details["branch"] == "approach"
    assert r.value == pytest.approx(-SN_SEED001, rel=0.01)
    assert abs(r.details["contact_point"] - 150e-9) < 5e-9
    noiseless_z, noiseless_v = simulate_approach_curve(SN_SEED001, 150e-9, 0.0, 400e-9, 500)
    exact = normal_sensitivity_from_curve(noiseless_z, noiseless_v)
    assert exact.value == pytest.approx(SN_SEED001, rel=1e-9)
    assert exact.details["contact_point"] == pytest.approx(150e-9, abs=1e-12)


def test_approach_curve_without_contact_is_rejected():
    z = np.linspace(0, 300e-9, 300)
    v = 0.01 + np.random.default_rng(1).normal(0, 1e-3, 300)
    with pytest.raises(ForceError, match="no contact found"):
        normal_sensitivity_from_curve(z, v)


# ---- wedge -------------------------------------------------------------------------------------------
def slopes_from_force_balance(tilt, mu, gl, normal_gain):
    """dV_h/dV_v sliding up and down, from two points of the force balance (not from the closed form)."""
    out = []
    for direction in ("up", "down"):
        fz, fy = wedge_forces(np.array([5e-9, 50e-9]), tilt, mu, 2e-9, direction)
        out.append(((fy[1] - fy[0]) / gl) / ((fz[1] - fz[0]) / normal_gain))
    return out


@pytest.mark.parametrize("tilt_deg", [5.0, 10.0, 20.0])
def test_wedge_round_trip_seed001_values(tilt_deg):
    tilt = math.radians(tilt_deg)
    s_up, s_dn = slopes_from_force_balance(tilt, MU_SEED001, GL_SEED001, NORMAL_GAIN)
    gl, mu, other = wedge_from_slopes(s_up, s_dn, tilt, NORMAL_GAIN, friction_branch="high")
    assert gl == pytest.approx(GL_SEED001, rel=1e-12)
    assert mu == pytest.approx(MU_SEED001, rel=1e-12)
    # the partner root 1/mu fits the same slopes (which is why a branch must be chosen)
    assert other[0] == pytest.approx(1 / MU_SEED001, rel=1e-12)
    s2 = slopes_from_force_balance(tilt, other[0], other[1], NORMAL_GAIN)
    assert s2 == pytest.approx([s_up, s_dn], rel=1e-12)
    with pytest.raises(ForceError, match="equally well; pass friction_branch='low' or 'high'"):
        wedge_from_slopes(s_up, s_dn, tilt, NORMAL_GAIN)
    # the thesis' Eq. 23-24 use dV_v/dV_h: the inverted ratio does not give the values back
    try:
        wrong = wedge_from_slopes(1 / s_up, 1 / s_dn, tilt, NORMAL_GAIN, friction_branch="high")
        assert abs(wrong[0] / GL_SEED001 - 1) > 0.1 or abs(wrong[1] / MU_SEED001 - 1) > 0.1
    except ForceError:
        pass


def test_wedge_low_friction_and_automatic_branch():
    tilt, mu, gl = math.radians(30.0), 0.4, 80e-9
    s_up, s_dn = slopes_from_force_balance(tilt, mu, gl, NORMAL_GAIN)
    # 1/mu = 2.5 > cot(30 deg) = 1.73: sliding up would lift the tip, so only mu = 0.4 is admissible
    got_gl, got_mu, other = wedge_from_slopes(s_up, s_dn, tilt, NORMAL_GAIN)
    assert (got_gl, got_mu, other) == (pytest.approx(gl, rel=1e-12), pytest.approx(mu, rel=1e-12), None)
    with pytest.raises(ForceError, match="the high root .* is not admissible"):
        wedge_from_slopes(s_up, s_dn, tilt, NORMAL_GAIN, friction_branch="high")
    # frictionless limit
    s_up, s_dn = slopes_from_force_balance(tilt, 0.0, gl, NORMAL_GAIN)
    got_gl, got_mu, _ = wedge_from_slopes(s_up, s_dn, tilt, NORMAL_GAIN)
    assert got_mu == pytest.approx(0.0, abs=1e-12) and got_gl == pytest.approx(gl, rel=1e-12)


def _sliding(seed, tilt=math.radians(10.0)):
    loads = np.linspace(2e-9, 15e-9, 400)
    kw = dict(adhesion=1e-9, noise_vertical=1e-4, noise_lateral=1e-3, lateral_offset=0.05)
    vu, hu = simulate_wedge_sliding(loads, tilt, MU_SEED001, GL_SEED001, NORMAL_GAIN, "up", seed=2 * seed, **kw)
    vd, hd = simulate_wedge_sliding(loads, tilt, MU_SEED001, GL_SEED001, NORMAL_GAIN, "down", seed=2 * seed + 1, **kw)
    return wedge_calibration(vu, hu, vd, hd, tilt, NORMAL_GAIN, friction_branch="high")


def test_wedge_noisy_data_within_stated_uncertainty():
    w = _sliding(0)
    assert abs(w.lateral_gain.value - GL_SEED001) < 3 * w.lateral_gain.uncertainty
    assert abs(w.friction.value - MU_SEED001) < 3 * w.friction.uncertainty
    assert w.lateral_gain.uncertainty / abs(GL_SEED001) < 0.01
    lo, hi = w.friction.confidence_interval
    assert lo < MU_SEED001 < hi
    assert w.other[0] == pytest.approx(1 / w.friction.value, rel=1e-9)
    # the stated uncertainty matches the scatter over repeated experiments
    zg, zm = [], []
    for seed in range(1, 61):
        w = _sliding(seed)
        zg.append((w.lateral_gain.value - GL_SEED001) / w.lateral_gain.uncertainty)
        zm.append((w.friction.value - MU_SEED001) / w.friction.uncertainty)
    assert 0.7 < np.std(zg) < 1.35 and abs(np.mean(zg)) < 0.5
    assert 0.7 < np.std(zm) < 1.35 and abs(np.mean(zm)) < 0.5


def test_wedge_noiseless_data_with_adhesion_and_offset():
    tilt = math.radians(15.0)
    loads = np.linspace(1e-9, 20e-9, 50)
    vu, hu = simulate_wedge_sliding(loads, tilt, 0.3, 40e-9, NORMAL_GAIN, "up", adhesion=3e-9, lateral_offset=-0.2)
    vd, hd = simulate_wedge_sliding(loads, tilt, 0.3, 40e-9, NORMAL_GAIN, "down", adhesion=3e-9, lateral_offset=-0.2)
    w = wedge_calibration(vu, hu, vd, hd, tilt, NORMAL_GAIN, friction_branch="low")
    assert w.lateral_gain.value == pytest.approx(40e-9, rel=1e-9)
    assert w.friction.value == pytest.approx(0.3, rel=1e-9)
    assert np.max(np.abs(w.lateral_gain.residuals)) < 1e-9


# ---- thermal noise ---------------------------------------------------------------------------------
def test_sho_psd_area():
    p0, f0, q = 2e-26, 12e3, 25.0
    area = integrate.quad(lambda f: sho_psd(f, 0.0, p0, f0, q), 0, 2 * f0, limit=500, points=[f0])[0]
    area += integrate.quad(lambda f: sho_psd(f, 0.0, p0, f0, q), 2 * f0, np.inf, limit=500)[0]
    assert area == pytest.approx(0.5 * math.pi * p0 * f0 * q, rel=1e-7)


def test_thermal_trace_variance_is_equipartition():
    k, temp = 0.3, 300.0
    tr = simulate_thermal_trace(k, 10e3, 30.0, 200e3, 2**19, temperature=temp, correction=1.0, seed=2)
    # ~2.6 s of a mode with 1 ms correlation time: the variance is known to ~2 %
    assert np.var(tr) == pytest.approx(BOLTZMANN * temp / k, rel=0.06)


@pytest.mark.parametrize("seed, k, f0, q, correction", [
    (1, 0.3, 10e3, 30.0, OPTICAL_LEVER_FIRST_MODE),
    (2, 2.4, 60e3, 50.0, OPTICAL_LEVER_FIRST_MODE),
    (3, 38.6, 20e3, 8.0, TRUE_DEFLECTION_FIRST_MODE),
])
def test_thermal_round_trip(seed, k, f0, q, correction):
    fs = 20 * f0
    tr = simulate_thermal_trace(k, f0, q, fs, 2**19, correction=correction, detector_noise=0.0, seed=seed)
    r = thermal_spring_constant(tr, fs, correction=correction)
    assert abs(r.value - k) < 3 * r.uncertainty
    # 2^19 samples hold ~1000-10000 correlation times Q / (pi f0): a few per cent
    assert r.uncertainty / k < 0.06
    assert r.details["resonance"] == pytest.approx(f0, rel=0.01)
    assert r.details["quality"] == pytest.approx(q, rel=0.15)
    assert abs(np.mean(r.residuals)) < 0.05


def test_thermal_with_detector_noise_floor():
    k, f0, fs = 0.3, 10e3, 200e3
    clean = simulate_thermal_trace(k, f0, 30.0, fs, 2**19, seed=4)
    floor = 0.3 * np.std(clean)  # adds 9 % to the variance
    tr = simulate_thermal_trace(k, f0, 30.0, fs, 2**19, detector_noise=floor, seed=4)
    r = thermal_spring_constant(tr, fs)
    assert abs(r.value - k) < 3 * r.uncertainty
    # the white floor is fitted: one-sided density of white noise is 2 sigma^2 / fs
    assert r.details["white"] == pytest.approx(2 * floor**2 / fs, rel=0.1)
    # plain equipartition of the whole trace is biased low by the floor; the fit is not
    naive = OPTICAL_LEVER_FIRST_MODE * BOLTZMANN * 298.15 / np.var(tr)
    assert naive < 0.95 * k < r.value


# ---- [Alabdulmuhsin]: force scaling tables 4.4 - 4.6 -----------------------------------------------------------
def test_seed001_force_scaling_tables():
    g = signal_to_haptic_force_gain(15e6, K_SEED001, SN_SEED001, GL_SEED001, length=450e-6, tip_height=15e-6)
    # Table 4.4 (magnitudes)
    assert g.normal_per_signal == pytest.approx(5.0265, abs=5e-5)
    assert abs(g.lateral_per_signal) == pytest.approx(0.9567, abs=5e-5)
    # Table 4.5: F_h,z for delta_z = 0, 100, 200, 500, 1000 nm (the 700 nm row reads 3.38 N but
    # K_f k 700 nm = 3.15 N; 3.38 N is the 750 nm value - a typo in the thesis)
    for dz, fh in ((0, 0.0), (100, 0.45), (200, 0.9), (500, 2.25), (1000, 4.5)):
        assert g.normal_per_deflection * dz * 1e-9 == pytest.approx(fh, abs=5e-3)
    assert g.normal_per_deflection * 750e-9 == pytest.approx(3.38, abs=5e-3)
    # Table 4.6: F_h,y for delta_y (theta_x = delta_y / h in degrees)
    for dy, theta_deg, fh in ((10, 0.04, 0.26), (25, 0.10, 0.64), (50, 0.19, 1.28), (100, 0.38, 2.57),
                              (150, 0.57, 3.85)):
        assert abs(g.lateral_per_displacement) * dy * 1e-9 == pytest.approx(fh, abs=5e-3)
        assert math.degrees(dy * 1e-9 / 15e-6) == pytest.approx(theta_deg, abs=5e-3)
    # F_n = k S_n V_v (Eq. 13-14): 335.1 nN/V
    assert K_SEED001 * SN_SEED001 == pytest.approx(335.1e-9, rel=1e-12)
    bare = signal_to_haptic_force_gain(15e6, K_SEED001, SN_SEED001, GL_SEED001)
    assert bare.lateral_per_displacement is None


# ---- bad input ---------------------------------------------------------------------------------------
def test_bad_input():
    with pytest.raises(ForceError, match="same length"):
        vertical_sensitivity_from_steps([1e-9, 2e-9, 3e-9], [0.1, 0.2])
    with pytest.raises(ForceError, match="a signal change is zero"):
        vertical_sensitivity_from_steps([1e-9, 2e-9], [0.1, 0.0])
    with pytest.raises(ForceError, match="contains NaN"):
        vertical_sensitivity_from_steps([1e-9, np.nan], [0.1, 0.2])
    with pytest.raises(ForceError, match="model must be 'end_load' or 'chord'"):
        lateral_sensitivity_from_vertical(706e-9, 1e-4, model="tangent")
    with pytest.raises(ForceError, match="length must be positive"):
        lateral_sensitivity_from_vertical(706e-9, 0.0)
    with pytest.raises(ForceError, match="pass -z if it decreases"):
        normal_sensitivity_from_curve(np.linspace(1e-6, 0, 100), np.zeros(100))
    with pytest.raises(ForceError, match="branch must be 'approach' or 'retract'"):
        normal_sensitivity_from_curve(np.linspace(0, 1e-6, 100), np.zeros(100), branch="both")
    with pytest.raises(ForceError, match="signal contains NaN"):
        normal_sensitivity_from_curve(np.linspace(0, 1e-6, 100), np.full(100, np.nan))
    with pytest.raises(ForceError, match=r"tilt must be in \(0, pi/2\)"):
        wedge_from_slopes(-1.0, 1.0, 0.0, NORMAL_GAIN)
    with pytest.raises(ForceError, match="negative friction coefficient"):
        s_up, s_dn = slopes_from_force_balance(math.radians(10), 0.5, GL_SEED001, NORMAL_GAIN)
        wedge_from_slopes(s_dn, s_up, math.radians(10), NORMAL_GAIN)
    with pytest.raises(ForceError, match="slope_up must be finite and non-zero"):
        wedge_from_slopes(0.0, 1.0, 0.2, NORMAL_GAIN)
    with pytest.raises(ForceError, match="the load must change while sliding"):
        wedge_calibration(np.ones(5), np.arange(5.0), np.arange(5.0), np.arange(5.0), 0.2, NORMAL_GAIN)
    with pytest.raises(ForceError, match="needs at least 4096 samples"):
        thermal_spring_constant(np.zeros(100), 1e5)
    with pytest.raises(ForceError, match=r"correction must be in \(0, 1\]"):
        thermal_spring_constant(np.zeros(5000), 1e5, correction=1.2)
    with pytest.raises(ForceError, match="sample_rate must be positive"):
        thermal_spring_constant(np.zeros(5000), -1.0)
    with pytest.raises(ForceError, match="below the Nyquist frequency"):
        simulate_thermal_trace(0.3, 60e3, 30.0, 100e3, 1000)
    with pytest.raises(ForceError, match="force_scale must be positive"):
        signal_to_haptic_force_gain(0.0, 0.3, 1e-6, 1e-8)
    with pytest.raises(ForceError, match="give both length and tip_height"):
        signal_to_haptic_force_gain(1e6, 0.3, 1e-6, 1e-8, length=1e-4)
