"""Virtual AFM: [Alabdulmuhsin] stages, photodiode noise, cantilever spring and the engage of Fig. 3.10."""
from __future__ import annotations

import math

import numpy as np
import pytest

from arsurf.instrument.engage import engage
from arsurf.errors import InstrumentError
from arsurf.instrument.instrument import (
    RECTANGULAR_NOISE,
    TRIANGULAR_NOISE,
    PhotodiodeNoise,
    VirtualAFM,
    expected_range,
)
from arsurf.instrument.stages import MICRO_STAGE, NANO_STAGE, NANO_STAGE_XY, PICOCUBE, Stage
from arsurf.scan.scan import Scan
from tests.support.real_scans import real_scan_path

K = 0.3  # N/m, [Alabdulmuhsin] Table 4.1
S_N = 1117e-9  # m per signal unit, [Alabdulmuhsin] Sec. 4.1.1


# ------------------------------------------------------------------------------------------------
# stages
# ------------------------------------------------------------------------------------------------


def test_stage_presets_are_seed_001s():
    assert (MICRO_STAGE.travel, MICRO_STAGE.resolution, MICRO_STAGE.max_velocity) == (25e-3, 0.05e-6, 1.5e-3)
    assert (NANO_STAGE.travel, NANO_STAGE.resolution) == (50e-6, 0.2e-9)
    assert NANO_STAGE_XY.travel == 100e-6
    assert (PICOCUBE.travel, PICOCUBE.resolution) == (5e-6, 0.1e-9)


def test_stage_quantizes_and_refuses_targets_outside_its_travel():
    assert MICRO_STAGE.quantize(0.16e-6) == 0.15e-6
    assert MICRO_STAGE.quantize(0.48e-6) == 0.5e-6
    steps = np.diff([MICRO_STAGE.quantize(k * 0.16e-6) for k in range(40)])
    # the commanded 0.16 um staircase becomes steps of 0.15 and 0.20 um, never more than the sweep
    assert set(np.round(steps * 1e9, 6)) == {150.0, 200.0}
    move = PICOCUBE.move(0.0, 1.00004e-6)
    assert move.end[0] == 1e-6
    with pytest.raises(InstrumentError, match=r"outside the travel \[0, 5e-06\] m"):
        PICOCUBE.move(0.0, 6e-6)
    with pytest.raises(InstrumentError, match="resolution must be positive"):
        Stage("bad", travel=1e-6, resolution=0.0, max_velocity=1.0, max_acceleration=1.0)


# ------------------------------------------------------------------------------------------------
# photodiode noise
# ------------------------------------------------------------------------------------------------


def test_expected_range_against_closed_form_and_monte_carlo(rng):
    assert expected_range(2) == pytest.approx(2 / math.sqrt(math.pi), rel=1e-9)
    mc = np.mean([np.ptp(rng.standard_normal(1000)) for _ in range(400)])
    assert expected_range(1000) == pytest.approx(mc, rel=0.01)


def test_rectangular_noise_spans_seed_001s_14_mV_over_5_s():
    pps = []
    for seed in range(12):
        noise, _ = RECTANGULAR_NOISE.generate(50_000, np.random.default_rng(seed))
        pps.append(np.ptp(noise))
    assert np.median(pps) == pytest.approx(0.0140, rel=0.06)
    # seeded: the same seed gives the same record
    a, _ = RECTANGULAR_NOISE.generate(100, np.random.default_rng(7))
    b, _ = RECTANGULAR_NOISE.generate(100, np.random.default_rng(7))
    assert np.array_equal(a, b)


def test_triangular_noise_has_its_low_frequency_share():
    noise, _ = TRIANGULAR_NOISE.generate(200_000, np.random.default_rng(5))
    white, _ = RECTANGULAR_NOISE.generate(200_000, np.random.default_rng(5))
    f = np.fft.rfftfreq(noise.size, 1 / 10e3)

    def low_share(x):
        p = np.abs(np.fft.rfft(x - x.mean())) ** 2
        return p[(f > 0) & (f < 60)].sum() / p[f > 0].sum()

    assert low_share(white) == pytest.approx(60 / 5000, rel=0.2)  # white: its bandwidth share
    # a first-order (Lorentzian) component with corner f_c has arctan(f / f_c) / arctan(f_N / f_c)
    # of its power below f; half the variance is in it
    lf = TRIANGULAR_NOISE.low_frequency_fraction
    expected = lf * math.atan(1.0) / math.atan(5000 / 60) + (1 - lf) * 60 / 5000
    assert low_share(noise) == pytest.approx(expected, rel=0.1)
    assert np.std(noise) == pytest.approx(TRIANGULAR_NOISE.sigma, rel=0.1)


def test_noise_rejects_nonsense():
    with pytest.raises(InstrumentError, match="peak_to_peak must be positive"):
        PhotodiodeNoise(peak_to_peak=-1.0)
    with pytest.raises(InstrumentError, match=r"low_frequency_fraction must be in \[0, 1\)"):
        PhotodiodeNoise(0.01, low_frequency_fraction=1.0)


# ------------------------------------------------------------------------------------------------
# the simulated instrument
# ------------------------------------------------------------------------------------------------


def test_spring_and_photodiode_model():
    afm = VirtualAFM(surface=2e-9, probe_height=100e-9, signal_offset=-0.2, seed=1)
    free = afm.dwell(0.5)
    assert np.mean(free) == pytest.approx(-0.2, abs=3 * RECTANGULAR_NOISE.sigma / math.sqrt(free.size) * 3)
    afm.move("nano", 150e-9)  # the sample rises 150 nm: 52 nm past contact
    h = afm.history()
    assert h.gap[-1] == pytest.approx(-52e-9, abs=1e-15)
    assert h.deflection[-1] == pytest.approx(52e-9, abs=1e-15)
    assert h.force[-1] == pytest.approx(K * 52e-9, rel=1e-12)
    sig = afm.dwell(0.2)
    assert np.mean(sig) == pytest.approx(-0.2 + 52e-9 / S_N, abs=1e-3)
    # the normalised signal saturates at +-1 (a 2 um bend needs 1.8 signal units)
    afm.move("micro", 2e-6)
    assert np.all(afm.dwell(0.01) == 1.0)
    # the LSPB move is sampled at the loop rate, with its limits
    t = h.time[h.time > 0.5]
    z = h.nano[h.time > 0.5]
    v = np.diff(z) / np.diff(t)
    assert v.max() <= NANO_STAGE.max_velocity * (1 + 1e-9)


def test_virtual_afm_input_checks():
    with pytest.raises(InstrumentError, match="probe_height must be finite"):
        VirtualAFM(probe_height=np.nan)
    with pytest.raises(InstrumentError, match="outside the scan"):
        VirtualAFM(Scan(np.zeros((4, 4)), 1e-9, 1e-9), probe_height=1e-6, tip_xy=(1e-6, 0.0))
    with pytest.raises(InstrumentError, match="stage must be one of"):
        VirtualAFM(probe_height=1e-6).move("z", 1e-9)


# ------------------------------------------------------------------------------------------------
# engage ([Alabdulmuhsin] Fig. 3.10)
# ------------------------------------------------------------------------------------------------

SETPOINT = 0.05  # signal units: 55.9 nm of bending, 16.8 nN
FORCE_LIMIT = 20e-9


def check_engage(result, afm, setpoint=SETPOINT, fine_step=1e-9):
    h = result.history
    assert result.engaged and result.reason == "setpoint"
    # the force history never exceeds the limit; the lever stops within one step (+noise) of
    # the set point
    assert h.force.max() <= FORCE_LIMIT
    assert result.max_force == h.force.max()
    bend = setpoint * S_N
    assert bend - 2e-9 <= h.deflection[-1] <= bend + fine_step + 2e-9
    # no height is skipped: the sample rises into new territory by at most one fine step at a time
    top = np.maximum.accumulate(h.micro + h.nano + h.pico)
    assert np.diff(top).max() <= fine_step * (1 + 1e-6)
    # the coarse stage stepped 0.15/0.20 um (its resolution) after each full fine sweep
    settled = h.micro[1:][np.diff(h.micro) == 0.0]  # positions held for more than one tick
    micro_moves = np.diff(np.unique(settled))
    assert np.all((np.abs(micro_moves - 0.15e-6) < 1e-12) | (np.abs(micro_moves - 0.2e-6) < 1e-12))


@pytest.mark.slow
def test_engage_from_5_um_above_a_flat_sample():
    afm = VirtualAFM(surface=30e-9, probe_height=30e-9 + 5e-6, signal_offset=0.1, seed=11)
    result = engage(afm, setpoint=SETPOINT, force_limit=FORCE_LIMIT)
    check_engage(result, afm)
    assert result.coarse_steps == 31  # 5 um / 0.16 um, the last sweep finds the surface
    h = result.history
    first_contact = int(np.argmax(h.force > 0.0))
    last_coarse_move = int(np.nonzero(np.diff(h.micro))[0][-1])
    assert first_contact > last_coarse_move  # the tip touches only during the last fine sweep


@pytest.mark.slow
def test_engage_from_5_um_above_a_real_scan():
    from arsurf.scan.io import load_scan

    scan = load_scan(real_scan_path("2018-02-09_1506_PH_dt20nmwindow1_Z_C.gsf"))
    cx, cy = 0.5 * scan.size[0], 0.5 * scan.size[1]
    under_tip = VirtualAFM(scan, probe_height=0.0, tip_xy=(cx, cy)).surface_height
    afm = VirtualAFM(scan, probe_height=under_tip + 5e-6, tip_xy=(cx, cy), seed=2)  # 5 um above
    result = engage(afm, setpoint=SETPOINT, force_limit=FORCE_LIMIT, max_coarse_steps=40)
    check_engage(result, afm)


def test_engage_with_the_picocube_as_fine_stage():
    afm = VirtualAFM(surface=0.0, probe_height=0.7e-6, seed=4, deflection_sensitivity=-S_N)  # [Alabdulmuhsin]'s sign
    result = engage(afm, setpoint=SETPOINT, fine_stage="pico", force_limit=FORCE_LIMIT)
    check_engage(result, afm)
    assert np.mean(afm.dwell(0.01)) < -0.04  # a negative sensitivity: the signal goes down


def test_safety_layer_aborts_before_the_force_limit():
    afm = VirtualAFM(surface=0.0, probe_height=0.3e-6, seed=9)
    # a set point of 0.5 (167 nN) is beyond the 20 nN limit: the safety layer must stop first
    result = engage(afm, setpoint=0.5, force_limit=FORCE_LIMIT)
    assert not result.engaged and result.reason == "force_limit"
    noise_margin = 5 * RECTANGULAR_NOISE.sigma * S_N * K
    assert result.max_force <= FORCE_LIMIT + K * 1e-9 + noise_margin
    assert afm.position["nano"] == 0.0 and result.history.force[-1] == 0.0  # retracted


def test_engage_settings_are_checked():
    afm = VirtualAFM(probe_height=1e-6)
    with pytest.raises(InstrumentError, match="must not exceed fine_range"):
        engage(afm, SETPOINT, coarse_step=0.3e-6)
    with pytest.raises(InstrumentError, match=r"setpoint must be a signal change in \(0, 1\)"):
        engage(afm, 1.5)
    with pytest.raises(InstrumentError, match="must be different stages"):
        engage(afm, SETPOINT, fine_stage="micro")
