"""Synthetic scans: geometry measured back (steps, tube and particle heights, volumes), roughness
statistics, seeds, the demo set on disk, and bad parameters."""
from __future__ import annotations

import math

import numpy as np

from arsurf.scan.io import load_scan
import pytest

import arsurf
from arsurf.errors import ScanError
from arsurf.scan import synthetic as syn
from arsurf.scan.level import level
from arsurf.scan.scan import Scan
from arsurf.scan.synthetic import SEED000_STEPS
from arsurf.errors import SyntheticError


def _measure_step(scan: Scan, axis: str = "x", guard_px: int = 6) -> float:
    """Step height by a two-level least-squares fit: z = a + b x + c y + h [top], with the pixels
    near the edges left out. Top/bottom come from thresholding the plane-levelled map."""
    z = level(scan, "plane").heights
    top = z > 0.5 * (np.percentile(z, 5) + np.percentile(z, 95))
    along = top if axis == "x" else top.T
    edge = np.zeros(along.shape, bool)
    change = np.diff(along.astype(int), axis=1) != 0
    for k in range(-guard_px, guard_px + 1):
        edge[:, max(k, 0) : along.shape[1] - 1 + min(k, 0)] |= change[:, max(-k, 0) : along.shape[1] - 1 - max(k, 0)]
    edge = edge if axis == "x" else edge.T
    y, x = np.mgrid[0 : scan.shape[0], 0 : scan.shape[1]]
    use = ~edge
    A = np.stack([np.ones(use.sum()), x[use] * scan.dx, y[use] * scan.dy, top[use].astype(float)], axis=1)
    coef, *_ = np.linalg.lstsq(A, scan.heights[use], rcond=None)
    return float(coef[3])


# ---------------------------------------------------------------------------------------------
# calibration gratings ([MWCNT])


@pytest.mark.parametrize("step,noise", list(zip(SEED000_STEPS, (0.5e-9, 1e-9, 2e-9))))
def test_grating_step_heights_are_measured_back(step, noise):
    s = syn.calibration_grating(step, shape=(64, 256), pixel=25e-9, edge_width=100e-9, noise=noise,
                                tilt=(1.5e-3, -0.8e-3), seed=7)
    h = _measure_step(s)
    # the fit uses ~12000 pixels: standard error of h ~ 2 noise / sqrt(12000) = 0.02 noise
    assert abs(h - step) < 0.1 * noise


def test_seed000_calibration_gives_k_v_706_nm_per_volt_from_the_measured_steps():
    # [MWCNT], section 2.3.1: steps of 20, 101.8 and 500 nm gave 32, 156 and 710 mV of vertical
    # PSD signal; k_v is the slope of deflection against signal (Fig. 4): 706 nm/V
    volts = np.array([32e-3, 156e-3, 710e-3])
    heights = np.array([_measure_step(syn.calibration_grating(h, noise=1e-9, tilt=(1e-3, 0), seed=i))
                        for i, h in enumerate(SEED000_STEPS)])
    k_v = float(heights @ volts / (volts @ volts))  # line through the origin
    assert k_v == pytest.approx(706e-9, rel=0.01)


def test_grating_profile_plateaus_edges_and_axis():
    s = syn.calibration_grating(100e-9, shape=(4, 400), pixel=10e-9, pitch=1e-6, duty=0.4, edge_width=50e-9,
                                center=2e-6)
    x = s.x
    z = s.heights[0]
    c = np.mod(x - 2e-6 + 0.5e-6, 1e-6) - 0.5e-6
    np.testing.assert_array_equal(z[np.abs(c) <= 0.2e-6 - 25e-9], 100e-9)  # plateau
    np.testing.assert_array_equal(z[np.abs(c) >= 0.2e-6 + 25e-9], 0.0)  # base
    mid = np.isclose(np.abs(c), 0.2e-6, atol=1e-12)  # half height at the nominal edge
    assert mid.any() and np.allclose(z[mid], 50e-9)
    assert np.mean(z > 50e-9) == pytest.approx(0.4, abs=0.01)  # duty cycle
    sy = syn.calibration_grating(100e-9, shape=(400, 4), pixel=10e-9, pitch=1e-6, duty=0.4, edge_width=50e-9,
                                 center=2e-6, axis="y")
    np.testing.assert_array_equal(sy.heights[:, 0], z)


# ---------------------------------------------------------------------------------------------
# sinusoid


def test_sinusoid_keeps_the_signature_of_the_package_docstring_and_is_exact():
    s = arsurf.synthetic.sinusoid(shape=(32, 32), pixel=10e-9, amplitude=5e-9, period=160e-9)
    assert s.shape == (32, 32) and s.dx == s.dy == 10e-9 and s.source == "synthetic:sinusoid"
    expected = 5e-9 * np.sin(2 * np.pi * np.arange(32) * 10e-9 / 160e-9)
    np.testing.assert_allclose(s.heights, np.tile(expected, (32, 1)), rtol=0, atol=1e-14 * 5e-9)


def test_sinusoid_direction_and_period_show_in_the_spectrum():
    theta = math.atan2(3, 4)  # wave vector (4, 3) cycles over the 64 x 64 scan
    L = 64 * 2e-9 / 5.0
    s = syn.sinusoid((64, 64), 2e-9, 1e-9, L, angle=theta)
    spec = np.abs(np.fft.fft2(s.heights))
    ky, kx = np.unravel_index(np.argmax(spec[:32, :32]), (32, 32))
    assert (kx, ky) == (4, 3)


# ---------------------------------------------------------------------------------------------
# nanotubes


def test_tube_height_equals_its_diameter_and_its_cross_section_area_is_analytic():
    r = 5e-9
    dy = 0.05e-9
    s = syn.nanotubes((400, 60), (1e-9, dy), diameter=2 * r, tubes=[(10e-9, 10e-9, 50e-9, 10e-9)])
    assert s.heights.max() == pytest.approx(2 * r, rel=1e-12)
    column = s.heights[:, 30]
    # upper half circle + the rectangle under the equator (the undercut lower half is hidden)
    area = math.pi * r**2 / 2 + 2 * r * r
    assert column.sum() * dy == pytest.approx(area, rel=0.01)
    # the hemispherical cap: one radius beyond the axis end the height is back to the substrate
    assert s.heights[200, 50] == pytest.approx(2 * r) and s.heights[200, 56] == 0.0
    tube = s.metadata["synthetic"]["tubes"][0]
    assert tube["diameter"] == 2 * r and tube["start"] == [10e-9, 10e-9]


def test_random_tubes_lie_inside_the_scan_apart_and_reach_their_diameter():
    d = 15e-9
    s = syn.nanotubes((256, 256), 4e-9, diameter=d, count=4, length=(200e-9, 500e-9), seed=11)
    tubes = s.metadata["synthetic"]["tubes"]
    assert len(tubes) == 4
    w = 255 * 4e-9
    for t in tubes:
        for x, y in (t["start"], t["end"]):
            assert d / 2 <= x <= w - d / 2 and d / 2 <= y <= w - d / 2
        length = math.dist(t["start"], t["end"])
        assert 200e-9 <= length <= 500e-9
        # pixels near the axis: the top is at the diameter to within the pixel sampling
        n = 50
        px = np.linspace(t["start"][0], t["end"][0], n) / 4e-9
        py = np.linspace(t["start"][1], t["end"][1], n) / 4e-9
        near = s.heights[np.round(py).astype(int), np.round(px).astype(int)]
        assert near.max() <= d * (1 + 1e-12) and np.median(near) > 0.95 * d
    for i in range(4):
        for j in range(i):
            a, b = tubes[i], tubes[j]
            assert syn._segment_distance((*a["start"], *a["end"]), (*b["start"], *b["end"])) > d


# ---------------------------------------------------------------------------------------------
# nanoparticles


@pytest.mark.parametrize("R,h", [(8e-9, 16e-9), (8e-9, 11e-9), (8e-9, 5e-9)])
def test_particle_height_and_volume_are_analytic(R, h):
    p = 0.1e-9
    s = syn.nanoparticles((240, 240), p, radius=R, height=h, centers=[(12e-9, 12e-9)])
    assert s.heights.max() == pytest.approx(h, rel=1e-12)
    zc = h - R  # centre height
    if h <= R:
        volume = math.pi * h**2 * (3 * R - h) / 3  # spherical cap
    else:
        # seen from above: a cylinder under the equator, plus the cap above it
        volume = math.pi * R**2 * zc + 2 * math.pi * R**3 / 3
    assert s.heights.sum() * p * p == pytest.approx(volume, rel=3e-3)


def test_random_particles_do_not_touch_and_have_the_sphere_height():
    s = syn.nanoparticles((200, 200), 2e-9, radius=[6e-9, 10e-9, 8e-9] * 4, count=12, seed=5)
    parts = s.metadata["synthetic"]["particles"]
    assert len(parts) == 12
    for i, a in enumerate(parts):
        ix, iy = (round(v / 2e-9) for v in a["center"])
        assert s.heights[iy, ix] > 0.95 * 2 * a["radius"]
        for b in parts[:i]:
            assert math.dist(a["center"], b["center"]) > a["radius"] + b["radius"]


# ---------------------------------------------------------------------------------------------
# rough surfaces


def test_rough_rms_is_right_within_the_statistical_tolerance():
    sigma, xi, px, n = 1e-9, 8e-9, 2e-9, 256
    # the mean square of a Gaussian field with Gaussian ACF fluctuates by sqrt(pi xi^2 / A)
    rel_sd = math.sqrt(math.pi * xi**2 / (n * px) ** 2)
    ms = np.array([np.mean(syn.rough((n, n), px, rms=sigma, correlation_length=xi, seed=s).heights ** 2)
                   for s in range(10)])
    assert np.all(np.abs(ms / sigma**2 - 1) < 4 * rel_sd)
    assert abs(ms.mean() / sigma**2 - 1) < 4 * rel_sd / math.sqrt(10)


def test_rough_autocorrelation_falls_to_one_over_e_at_the_correlation_length_on_both_axes():
    xi, dx, dy = 16e-9, 2e-9, 4e-9  # non-square pixels: 8 px along x, 4 px along y
    acf = np.zeros((128, 256))
    for seed in range(6):
        z = syn.rough((128, 256), (dx, dy), rms=1e-9, correlation_length=xi, seed=seed).heights
        f = np.fft.fft2(z)
        acf += np.real(np.fft.ifft2(f * np.conj(f))) / z.size
    acf /= acf[0, 0]
    assert acf[0, 8] == pytest.approx(math.exp(-1), abs=0.03)
    assert acf[4, 0] == pytest.approx(math.exp(-1), abs=0.03)
    assert acf[0, 16] == pytest.approx(math.exp(-4), abs=0.03)


def test_generators_are_reproducible_with_a_seed():
    for make in (lambda s: syn.rough((64, 64), 2e-9, correlation_length=8e-9, seed=s),
                 lambda s: syn.nanotubes((64, 64), 4e-9, count=1, length=100e-9, noise=1e-10, seed=s),
                 lambda s: syn.nanoparticles((64, 64), 2e-9, count=3, noise=1e-10, seed=s),
                 lambda s: syn.calibration_grating(noise=1e-9, seed=s)):
        a, b, c = make(3).heights, make(3).heights, make(4).heights
        assert np.array_equal(a, b) and not np.array_equal(a, c)
    g1 = syn.rough((32, 32), 2e-9, correlation_length=4e-9, seed=np.random.default_rng(9)).heights
    g2 = syn.rough((32, 32), 2e-9, correlation_length=4e-9, seed=9).heights
    assert np.array_equal(g1, g2)


def test_noise_and_tilt_are_what_was_asked():
    s = syn.sinusoid((200, 200), 1e-9, 0.0, 50e-9, noise=0.4e-9, tilt=(3e-3, -2e-3), seed=1)
    out = level(s, "plane")
    c = out.history[-1]["coefficients"]
    # slope standard error: noise / (sqrt(N) * rms of x) = 0.4e-9 / (200 * 57.7e-9) = 3.5e-5
    assert c["slope_x"] == pytest.approx(3e-3, abs=2e-4) and c["slope_y"] == pytest.approx(-2e-3, abs=2e-4)
    assert np.std(out.heights) == pytest.approx(0.4e-9, rel=0.03)  # 40000 samples: sd 0.35 %


# ---------------------------------------------------------------------------------------------
# demo set


def test_demo_scans_are_written_small_and_load_back(tmp_path):
    paths = syn.write_demo_scans(tmp_path / "scans")
    assert [p.stem for p in paths] == list(syn.DEMO_SCANS)
    assert sum(p.stat().st_size for p in paths) < 3e6
    steps = {}
    for p in paths:
        scan = load_scan(p)
        meta = scan.metadata
        assert scan.heights.shape[0] <= 256 and scan.heights.shape[1] <= 256
        assert meta["synthetic"]["generator"] in ("calibration_grating", "sinusoid", "nanotubes",
                                                  "nanoparticles", "rough")
        assert scan.channel == "Height" and meta["synthetic"]["noise"] > 0
        if p.stem.startswith("grating"):
            steps[meta["synthetic"]["step"]] = _measure_step(scan)
    assert sorted(steps) == sorted(SEED000_STEPS)
    for true, measured in steps.items():
        assert measured == pytest.approx(true, rel=0.01)
    again = syn.write_demo_scans(tmp_path / "again")  # deterministic
    for a, b in zip(paths, again):
        assert np.array_equal(load_scan(a).heights, load_scan(b).heights)


def test_the_packaged_demo_scan_is_the_one_the_generator_writes(tmp_path):
    """arsurf/data/nanotubes.npz (package data, what a wheel ships) is write_demo_scans' nanotubes."""
    from arsurf.data import bundled_scan

    written = {p.stem: p for p in syn.write_demo_scans(tmp_path)}
    shipped, fresh = load_scan(bundled_scan("nanotubes")), load_scan(written["nanotubes"])
    assert np.array_equal(shipped.heights, fresh.heights) and (shipped.dx, shipped.dy) == (fresh.dx, fresh.dy)
    assert shipped.metadata["synthetic"] == fresh.metadata["synthetic"]


# ---------------------------------------------------------------------------------------------
# bad parameters


@pytest.mark.parametrize(
    "call,match",
    [
        (lambda: syn.sinusoid((0, 10)), r"`shape` must be two positive integers \(ny, nx\)"),
        (lambda: syn.sinusoid((10, 10), -1e-9), r"pixel must be positive and finite \(got -1e-09 m\)"),
        (lambda: syn.sinusoid((10, 10), (1e-9, 0.0)), r"pixel \(dy\) must be positive"),
        (lambda: syn.sinusoid(period=0.0), r"period must be positive"),
        (lambda: syn.sinusoid(noise=-1e-9), r"noise must be >= 0"),
        (lambda: syn.sinusoid(tilt=(1e-3,)), r"`tilt` must have 2 values"),
        (lambda: syn.sinusoid(seed=-1), "`seed` must be a non-negative int"),
        (lambda: syn.calibration_grating(duty=1.2), r"`duty` must be in \(0, 1\)"),
        (lambda: syn.calibration_grating(edge_width=2e-6), "`edge_width`.*must be below"),
        (lambda: syn.calibration_grating(axis="z"), "`axis` must be 'x' or 'y'"),
        (lambda: syn.nanotubes((32, 32), 1e-9, count=5, length=(60e-9, 80e-9)), "could not place tube 1 of 5"),
        (lambda: syn.nanotubes(diameter=[1e-8, 2e-8], count=3), "`diameter` has 2 values for 3 objects"),
        (lambda: syn.nanoparticles(radius=5e-9, height=11e-9), "cannot exceed the sphere diameter"),
        (lambda: syn.nanoparticles((20, 20), 1e-9, radius=4e-9, count=40), "could not place particle"),
        (lambda: syn.rough(pixel=4e-9, correlation_length=2e-9), "shorter than the pixel along x"),
        (lambda: syn.rough((64, 64), 1e-9, correlation_length=20e-9), "exceeds a quarter of the scan side"),
    ],
)
def test_bad_parameters_raise_clear_errors(call, match):
    with pytest.raises(SyntheticError, match=match):
        call()
    assert issubclass(SyntheticError, ScanError) and issubclass(SyntheticError, ValueError)
