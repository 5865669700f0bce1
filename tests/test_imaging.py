"""The virtual AFM's images: the tip's dilation against the analytic image of a tube, the drift's
affine map, the feedback lag, the photodiode noise, and the instrument's scan_image."""
from __future__ import annotations

import math

import numpy as np
import pytest

from arsurf.errors import InstrumentError
from arsurf.instrument.imaging import (Sample, ScanSettings, ScanTruth, ThermalDrift, TipShape, acquire, dilate,
                                       pixel_noise)
from arsurf.instrument.instrument import PhotodiodeNoise, VirtualAFM
from arsurf.manipulation.nanotube import Nanotube
from arsurf.scan.io import load_scan, save_scan
from arsurf.scan.scan import Scan

FLAT = Scan(np.zeros((120, 120)), dx=5e-9, dy=5e-9)


def test_tip_profile_is_a_sphere_on_a_cone():
    tip = TipShape(10e-9, math.radians(30))
    rho = np.array([0.0, 5e-9, 10e-9 * math.cos(math.radians(30))])
    assert tip.height(rho) == pytest.approx(10e-9 - np.sqrt(1e-16 - rho**2), abs=1e-18)
    # beyond the tangent circle the slope is the cone's, 1/tan(theta)
    a, b = tip.height(20e-9), tip.height(30e-9)
    assert (b - a) / 10e-9 == pytest.approx(1.0 / math.tan(math.radians(30)))
    assert tip.reach(float(tip.height(25e-9))) == pytest.approx(25e-9)


def test_dilation_of_a_tube_is_the_analytic_image():
    """A cylinder of radius r imaged by a sphere R (the cone not reached) is the cylinder of radius
    r + R lowered by R (Nanotube.height_map with tip_radius), 2 sqrt(rR) wide at the base."""
    r, R, d = 5e-9, 20e-9, 1e-9
    tube = Nanotube(400e-9, 2 * r, x=100e-9, y=100e-9, angle=0.0)
    x = np.arange(200) * d
    xx, yy = np.meshgrid(x, x)
    surf = np.fmax(0.0, tube.height_map(xx, yy))
    img = dilate(surf, d, d, TipShape(R, math.radians(10)))
    want = np.fmax(0.0, tube.height_map(xx, yy, tip_radius=R))
    assert np.abs(img[60:140, 60:140] - want[60:140, 60:140]).max() < 0.1e-9  # the 1 nm grid: < 1 % of 2r
    half = np.abs(x - 100e-9)[img[:, 100] > 1e-12].max()  # across the tube (along y)
    assert half == pytest.approx(2 * math.sqrt(r * R), abs=d)


def test_a_spike_images_as_the_reflected_tip():
    z = np.zeros((41, 41))
    z[20, 20] = 8e-9
    tip = TipShape(6e-9, math.radians(25))
    img = dilate(z, 0.5e-9, 0.5e-9, tip)
    oy, ox = np.mgrid[-20:21, -20:21]
    want = np.maximum(8e-9 - tip.height(np.hypot(ox, oy) * 0.5e-9), 0.0)
    assert img == pytest.approx(want, abs=1e-20)


def test_drift_makes_an_affine_view_the_instrument_knows():
    """A narrow tube seen with drift: each line's ridge, mapped by the truth's affine map, lies on
    the tube's axis (the drift moved it by several pixels in the image)."""
    tube = Nanotube(500e-9, 6e-9, x=300e-9, y=300e-9, angle=math.radians(80))
    sample = Sample(FLAT, objects=[tube])
    drift = ThermalDrift(offset=(12e-9, -9e-9, 0.0), velocity=(0.4e-9, 0.3e-9, 0.0))
    st = ScanSettings((96, 96), (480e-9, 480e-9), origin=(60e-9, 60e-9), line_speed=4e-6, feedback_bandwidth=1e8)
    img, truth = acquire(sample, st, TipShape(8e-9), drift=drift)
    h = img.heights
    rows = np.arange(20, 76)
    cols = np.array([np.sum(np.arange(96) * np.clip(h[i] - 0.5 * h[i].max(), 0, None))
                     / np.sum(np.clip(h[i] - 0.5 * h[i].max(), 0, None)) for i in rows])
    p = truth.pixel_to_sample @ np.vstack([cols, rows, np.ones_like(cols)])
    a, u = tube.endpoints[0][:2], tube.direction
    off = (p[0] - a[0]) * -u[1] + (p[1] - a[1]) * u[0]  # distance from the axis line
    assert np.abs(off).max() < 0.15 * st.spacing[0]
    naive = np.array([60e-9 + cols * st.spacing[0], 60e-9 + rows * st.spacing[1]])  # without the drift
    assert np.abs((naive[0] - a[0]) * -u[1] + (naive[1] - a[1]) * u[0]).mean() > 2 * st.spacing[0]
    assert drift.offset[0] == pytest.approx(12e-9 + 0.4e-9 * st.duration)
    assert ScanTruth.from_metadata(img.metadata["virtual_afm"]).pixel_to_sample == pytest.approx(truth.pixel_to_sample)


def test_feedback_lag_shifts_a_step_along_the_trace():
    """A first-order loop of corner f_c lags a step by v / (2 pi f_c) (its time constant)."""
    step = Scan(np.where(np.arange(400)[None, :] >= 200, 5e-9, 0.0) * np.ones((20, 1)), dx=1e-9, dy=1e-9)
    v, fc = 10e-6, 200.0
    st = ScanSettings((200, 10), (200e-9, 10e-9), origin=(100e-9, 5e-9), line_speed=v, feedback_bandwidth=fc,
                      oversample=16)
    img, _ = acquire(Sample(step), st, TipShape(0.5e-9, math.radians(2)))  # a needle: the step stays sharp
    row = img.heights[5] / 5e-9
    # the lagged step reaches 1 - 1/e one time constant after the edge (x = 200 nm -> pixel 100)
    x_63 = np.interp(1 - math.exp(-1), row, np.arange(200) * 1e-9 + 100e-9)
    assert x_63 - 200e-9 == pytest.approx(v / (2 * math.pi * fc), abs=1.5e-9)


def test_noise_is_the_photodiodes_seen_through_the_sensitivity_and_seeded():
    noise = PhotodiodeNoise(peak_to_peak=0.014)
    st = ScanSettings((64, 64), (320e-9, 320e-9), line_speed=1e-6)
    sigma = pixel_noise(noise, 1117e-9, st.pixel_time)
    assert sigma == pytest.approx(noise.sigma * 1117e-9 / math.sqrt(st.pixel_time * noise.rate))
    a, _ = acquire(Sample(FLAT), st, TipShape(10e-9), noise_sigma=sigma, seed=4)
    b, _ = acquire(Sample(FLAT), st, TipShape(10e-9), noise_sigma=sigma, seed=4)
    c, _ = acquire(Sample(FLAT), st, TipShape(10e-9), noise_sigma=sigma, seed=5)
    assert np.std(a.heights) == pytest.approx(sigma, rel=0.05)
    assert np.array_equal(a.heights, b.heights) and not np.array_equal(a.heights, c.heights)


def test_the_virtual_afm_scans_its_sample_and_the_drift_differs_between_scans(tmp_path):
    tube = Nanotube(300e-9, 10e-9, x=300e-9, y=300e-9, angle=0.4)
    afm = VirtualAFM(FLAT, probe_height=1e-6, tip_xy=(1e-7, 1e-7), sample=Sample(FLAT, objects=[tube]),
                     drift=ThermalDrift(rate_xy=0.1e-9, rate_z=0.01e-9, seed=2), keep_history=False,
                     scan_settings=ScanSettings((64, 64), (500e-9, 500e-9), origin=(50e-9, 50e-9)))
    with pytest.raises(InstrumentError, match="not open"):
        afm.scan_image()
    with afm:
        t0 = afm.time
        before = afm.scan_image()
        after = afm.scan_image()
    v0 = before.metadata["virtual_afm"]["drift_velocity_m_per_s"]
    v1 = after.metadata["virtual_afm"]["drift_velocity_m_per_s"]
    assert v0 != v1
    assert afm.time == pytest.approx(t0 + 2 * 64 * 2 * 500e-9 / 2e-6)
    assert before.metadata["instrument"]["tip_radius_m"] == 10e-9 and before.channel == "Z"
    assert before.heights.max() == pytest.approx(10e-9, abs=1.5e-9)
    back = load_scan(save_scan(before, tmp_path / "before.npz"))
    assert np.array_equal(back.heights, before.heights) and back.dx == before.dx


def test_bad_imaging_inputs_are_one_line():
    with pytest.raises(InstrumentError, match="pixels must be"):
        ScanSettings((4, 64), (1e-7, 1e-7))
    with pytest.raises(InstrumentError, match="direction"):
        ScanSettings((64, 64), (1e-7, 1e-7), direction="sideways")
    with pytest.raises(InstrumentError, match="half_angle"):
        TipShape(1e-8, math.pi / 2)
    with pytest.raises(InstrumentError, match="dent"):
        Sample(FLAT, dent=np.zeros((3, 3)))
    with pytest.raises(InstrumentError, match="height_map"):
        Sample(FLAT, objects=[object()])
    with pytest.raises(InstrumentError, match="no sample"):
        with VirtualAFM(0.0, probe_height=1e-6) as afm:
            afm.scan_image()
