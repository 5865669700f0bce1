"""Filters: exact first-order step/frequency response, [Alabdulmuhsin]'s unstable forward Euler, Butterworth."""
from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from scipy import signal

from arsurf.errors import HapticsError
from arsurf.errors import HapticsWarning
from arsurf.haptics.filters import (
    ButterworthLowPass,
    LowPass,
    check_forward_euler,
    forward_euler_pole,
    lowpass_alpha,
)


def steady_state_response(filt, f, dt, periods_settle=20, periods_fit=10):
    """Drive channel 0 with sin(2 pi f t); least-squares fit of the output after the transient.

    Returns the complex gain (amplitude and phase) of the output relative to the input.
    """
    n_settle = max(int(round(periods_settle / (f * dt))), int(round(0.5 / dt)))  # >= 0.5 s of transient
    n_fit = int(round(periods_fit / (f * dt)))
    k = np.arange(n_settle + n_fit)
    x = np.sin(2 * np.pi * f * k * dt)
    y = np.empty_like(x)
    for i in range(x.size):
        y[i] = filt.step(np.array([x[i], 0.0, 0.0]))[0]
    kk = k[n_settle:]
    A = np.column_stack([np.sin(2 * np.pi * f * kk * dt), np.cos(2 * np.pi * f * kk * dt)])
    (a, b), *_ = np.linalg.lstsq(A, y[n_settle:], rcond=None)
    # a sin + b cos = Re{(a - j b)... }: gain G with y = |G| sin(wt + arg G) => G = a + j b
    return complex(a, b)


# ---------------------------------------------------------------------------------------------
# first order, exact (ZOH)
# ---------------------------------------------------------------------------------------------
def test_alpha_is_the_zoh_formula():
    assert lowpass_alpha(100.0, 1e-3) == pytest.approx(1 - math.exp(-2 * math.pi * 100.0 * 1e-3), rel=1e-15)
    # the thesis' 5 kHz at 10 kHz is harmless with the exact discretisation
    assert 0 < lowpass_alpha(5000.0, 1e-4) < 1


@pytest.mark.parametrize("fc, dt", [(10.0, 1e-3), (100.0, 1e-3), (5000.0, 1e-4), (50.0, 1e-4)])
def test_first_order_step_response_is_the_continuous_one_sampled(fc, dt):
    f = LowPass(cutoff=fc, dt=dt)
    wc = 2 * math.pi * fc
    k = np.arange(300)
    y = np.array([f.step([1.0, 2.0, -3.0]).copy() for _ in k])
    expected = 1.0 - np.exp(-wc * (k + 1) * dt)  # continuous step response at t_k + dT
    np.testing.assert_allclose(y[:, 0], expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(y[:, 1], 2 * expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(y[:, 2], -3 * expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("f", [1.0, 20.0, 100.0, 300.0])
def test_first_order_frequency_response(f):
    fc, dt = 50.0, 1e-3
    filt = LowPass(cutoff=fc, dt=dt)
    g = steady_state_response(filt, f, dt)
    h_discrete = complex(filt.frequency_response(f))
    # exact against the discrete filter's own response
    assert abs(g - h_discrete) < 1e-9
    # and close to the continuous one, |H| = 1/sqrt(1 + (f/fc)^2), where f*dt is small
    if f <= 100.0:
        assert abs(g) == pytest.approx(1 / math.sqrt(1 + (f / fc) ** 2), rel=0.05)


def test_first_order_cutoff_is_3db_down_in_the_continuous_limit():
    fc, dt = 10.0, 1e-5  # w_c dT = 6e-4: the discrete filter is the continuous one
    filt = LowPass(cutoff=fc, dt=dt)
    assert abs(filt.frequency_response(fc)) == pytest.approx(1 / math.sqrt(2), rel=1e-3)
    assert np.angle(filt.frequency_response(fc)) == pytest.approx(-math.pi / 4, abs=1e-3)


def test_first_order_holds_on_nonfinite_input_and_counts_it():
    f = LowPass(cutoff=100.0, dt=1e-3)
    y1 = f.step([1.0, 1.0, 1.0])
    y2 = f.step([np.nan, 1.0, 1.0])
    np.testing.assert_array_equal(y1, y2)
    assert np.isfinite(f.state).all() and f.nonfinite == 1
    y3 = f.step([1.0, 1.0, 1.0])
    np.testing.assert_allclose(y3, y1 + f.alpha * (1.0 - y1))  # state kept: the next step continues


# ---------------------------------------------------------------------------------------------
# [Alabdulmuhsin] Eq. 34: forward Euler
# ---------------------------------------------------------------------------------------------
def forward_euler_reference(wdt, n):
    """[Alabdulmuhsin] Eq. 34 literally: y[k+1] = (1 - dT w_c) y[k] + dT w_c x[k], unit step input."""
    y = [0.0]
    for _ in range(n):
        y.append((1 - wdt) * y[-1] + wdt * 1.0)
    return np.array(y)


def test_thesis_setting_is_caught():
    # f_c = 5 kHz at 10 kHz: w_c dT = pi > 2
    assert forward_euler_pole(5000.0, 1e-4) == pytest.approx(1 - math.pi)
    with pytest.raises(HapticsError, match=r"unstable: w_c\*dT = .*3\.1416 >= 2"):
        check_forward_euler(5000.0, 1e-4)
    with pytest.raises(HapticsError, match="unstable"):
        LowPass(cutoff=5000.0, dt=1e-4, method="forward_euler")
    with pytest.warns(HapticsWarning, match="unstable"):
        assert check_forward_euler(5000.0, 1e-4, on_unstable="warn") == pytest.approx(math.pi)


def test_thesis_recursion_really_diverges_and_zoh_does_not():
    wdt = 2 * math.pi * 5000.0 * 1e-4
    y_fe = forward_euler_reference(wdt, 40)
    # measured growth of the error |y - 1| per step equals |1 - w_c dT| = pi - 1
    err = np.abs(y_fe - 1.0)
    growth = err[1:] / err[:-1]
    np.testing.assert_allclose(growth, math.pi - 1, rtol=1e-9)
    assert err[-1] > 1e12
    f = LowPass(cutoff=5000.0, dt=1e-4)
    y = np.array([f.step([1.0, 0, 0])[0] for _ in range(40)])
    assert np.all((y > 0) & (y <= 1.0)) and y[-1] == pytest.approx(1.0, abs=1e-12)


def test_forward_euler_rings_between_1_and_2_and_is_fine_below():
    with pytest.warns(HapticsWarning, match="rings"):
        check_forward_euler(2500.0, 1e-4)  # w_c dT = pi/2
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        wdt = check_forward_euler(100.0, 1e-3)  # 0.628: monotone and stable
    f = LowPass(cutoff=100.0, dt=1e-3, method="forward_euler")
    assert f.alpha == pytest.approx(wdt)
    y = np.array([f.step([1.0, 0, 0])[0] for _ in range(30)])
    np.testing.assert_allclose(y, forward_euler_reference(wdt, 30)[1:], atol=1e-14)


def test_bad_settings_are_refused():
    with pytest.raises(HapticsError, match="cutoff must be positive"):
        LowPass(cutoff=-1.0, dt=1e-3)
    with pytest.raises(HapticsError, match="dt must be positive"):
        LowPass(cutoff=10.0, dt=0.0)
    with pytest.raises(HapticsError, match="method must be"):
        LowPass(cutoff=10.0, dt=1e-3, method="tustin")
    with pytest.raises(HapticsError, match=r"input must have shape \(3,\)"):
        LowPass(cutoff=10.0, dt=1e-3).step([1.0, 2.0])
    with pytest.raises(HapticsError, match="on_unstable"):
        check_forward_euler(10.0, 1e-3, on_unstable="ignore")


# ---------------------------------------------------------------------------------------------
# Butterworth (biquads)
# ---------------------------------------------------------------------------------------------
def test_butterworth_step_response_against_the_analytic_second_order():
    fc, dt = 10.0, 1e-4  # fc << fs: the bilinear map barely distorts
    f = ButterworthLowPass(cutoff=fc, dt=dt)
    n = 3000
    y = np.array([f.step([1.0, 1.0, 1.0])[0] for _ in range(n)])
    wn, zeta = 2 * math.pi * fc, 1 / math.sqrt(2)
    wd = wn * math.sqrt(1 - zeta**2)
    t = (np.arange(n) + 0.5) * dt  # bilinear (trapezoidal) step response sits half a sample late
    ref = 1 - np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta / math.sqrt(1 - zeta**2) * np.sin(wd * t))
    np.testing.assert_allclose(y, ref, atol=2e-4)
    # overshoot of a 2nd-order Butterworth: exp(-pi zeta / sqrt(1 - zeta^2)) = exp(-pi) = 4.32 %
    assert y.max() - 1 == pytest.approx(math.exp(-math.pi), rel=2e-3)


@pytest.mark.parametrize("order", [2, 4])
@pytest.mark.parametrize("f", [5.0, 50.0, 100.0, 300.0])
def test_butterworth_frequency_response_is_the_prewarped_analytic_one(order, f):
    fc, dt = 50.0, 1e-3
    filt = ButterworthLowPass(cutoff=fc, dt=dt, order=order)
    g = steady_state_response(filt, f, dt)
    ratio = math.tan(math.pi * f * dt) / math.tan(math.pi * fc * dt)
    expected = 1 / math.sqrt(1 + ratio ** (2 * order))
    assert abs(g) == pytest.approx(expected, rel=1e-6)
    assert abs(g - complex(filt.frequency_response(f))) < 1e-9
    if f == fc:
        assert 20 * math.log10(abs(g)) == pytest.approx(-3.0103, abs=1e-3)


def test_butterworth_kernel_matches_scipy_sosfilt(rng):
    filt = ButterworthLowPass(cutoff=120.0, dt=1e-3, channels=3, order=4)
    x = rng.normal(size=(500, 3))
    y = np.array([filt.step(row).copy() for row in x])
    ref = signal.sosfilt(filt.sos, x, axis=0)
    np.testing.assert_allclose(y, ref, atol=1e-12)


def test_butterworth_reset_starts_in_steady_state_and_holds_nan():
    filt = ButterworthLowPass(cutoff=30.0, dt=1e-3, initial=2.5)
    for _ in range(50):
        y = filt.step([2.5, 2.5, 2.5])
    np.testing.assert_allclose(y, 2.5, atol=1e-12)  # no start-up transient
    before = filt.state.copy()
    y_nan = filt.step([2.5, np.inf, 2.5])
    np.testing.assert_array_equal(y_nan, y)
    np.testing.assert_array_equal(filt.state, before)
    assert filt.nonfinite == 1


def test_butterworth_refuses_cutoff_at_nyquist():
    with pytest.raises(HapticsError, match=r"below the Nyquist frequency .* 5000 Hz"):
        ButterworthLowPass(cutoff=5000.0, dt=1e-4)
    with pytest.raises(HapticsError, match="order must be"):
        ButterworthLowPass(cutoff=10.0, dt=1e-3, order=0)
    with pytest.raises(HapticsError, match="channels must be"):
        ButterworthLowPass(cutoff=10.0, dt=1e-3, channels=0)
