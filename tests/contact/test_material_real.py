"""Material maps on the real PeakForce QNM file sample_0.spm (../shared/scans-real): its DMTModulus
is in Arb and its Adhesion in volts of deflection, so every conversion is stated here; the
statistics agree with the channel values through those conversions, and the model feels the
stiffest and the softest decile differently (indentation at one load, pull-off)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from arsurf.cli import main
from arsurf.contact.material_conversion import MaterialConversion
from arsurf.contact.material_map import build_material_map, material_map_from_file
from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.errors import MaterialMapError
from arsurf.force.cantilever import Cantilever
from arsurf.model import ARModel
from arsurf.scan.io import load_scan
from arsurf.scan.level import level
from arsurf.scan.scan import Scan
from arsurf.spline.fit import fit_surface
from tests.support.real_scans import real_scan_path
from tests.support.reference import ref_tick_at_load

R = 5e-9                                  # the file's own "Tip Radius: 5" (nm)
#: the stated conversions (assumptions: the file leaves both channels uncalibrated)
STATED = dict(modulus_scale=1.7e10, deflection_sensitivity=50e-9, spring_constant=40.0)


@pytest.fixture(scope="module")
def spm():
    return real_scan_path("sample_0.spm")


def test_uncalibrated_channels_are_refused_without_their_conversion(spm):
    with pytest.raises(MaterialMapError, match="DMTModulus.*'Arb', not Pa.*modulus_scale"):
        material_map_from_file(spm, MaterialConversion(R))
    with pytest.raises(MaterialMapError, match="volts of photodiode deflection"):
        material_map_from_file(spm, MaterialConversion(R, modulus_scale=1e10))


def _independent_statistics(spm, conv):
    """E* and w of the unmasked pixels, recomputed here from the raw channels and the stated
    conversion (NanoScope full scale from the Z scale, robust log outliers, DMT pull-off law)."""
    mod = load_scan(spm, channel="DMTModulus")
    adh = load_scan(spm, channel="Adhesion")
    v = mod.heights
    full = mod.metadata["z_per_lsb"] * (2.0 ** 31 - 1)
    ok = np.isfinite(v) & (v > 0) & (np.abs(v) < full * (1 - 1e-9))
    lv = np.log(np.where(ok, v * conv.modulus_scale, 1.0))
    med = np.median(lv[ok])
    mad = 1.4826 * np.median(np.abs(lv[ok] - med))
    ok &= np.abs(lv - med) <= conv.outlier_mads * mad
    es = v[ok] * conv.modulus_scale
    e_star = 1.0 / ((1 - conv.sample_poisson ** 2) / es + (1 - conv.tip_poisson ** 2) / conv.tip_modulus)
    f = adh.heights * conv.deflection_sensitivity * conv.spring_constant
    fok = np.isfinite(f) & (f != 0)
    fm = np.median(f[fok])
    fmad = 1.4826 * np.median(np.abs(f[fok] - fm))
    fok &= np.abs(f - fm) <= conv.outlier_mads * fmad
    w = np.maximum(f[fok], conv.adhesion_floor) / (2 * math.pi * conv.tip_radius)
    return e_star, w


def test_statistics_agree_with_the_channels_and_the_stated_conversions(spm, capsys):
    conv = MaterialConversion(R, regime="dmt", adhesion_floor=1e-9, **STATED)
    m = material_map_from_file(spm, conv)
    e_star, w = _independent_statistics(spm, conv)
    for name, values in (("reduced_modulus", e_star), ("work_of_adhesion", w)):
        st = m.statistics[name]
        assert st["pixels"] == values.size
        for key, q in (("median", 50), ("p5", 5), ("p95", 95)):
            assert st[key] == pytest.approx(np.percentile(values, q), rel=1e-12), (name, key)
    assert m.masked["modulus"]["saturated"] == 614 / 1024 ** 2 and m.masked["modulus"]["zero"] == 454 / 1024 ** 2
    # arsurf info --material prints the same figures, in GPa and mJ/m^2
    assert main(["info", str(spm), "--material", "--tip-radius-nm", "5", "--regime", "dmt", "--adhesion-floor-nn", "1",
                 "--modulus-scale", "1.7e10", "--deflection-sensitivity-nm-per-v", "50", "--spring-constant", "40"]) == 0
    out = capsys.readouterr().out
    st = m.statistics["reduced_modulus"]
    assert (f"median {st['median'] / 1e9:.6g}, 5-95 % {st['p5'] / 1e9:.6g} .. {st['p95'] / 1e9:.6g}") in out
    st = m.statistics["work_of_adhesion"]
    assert (f"median {st['median'] * 1e3:.6g}, 5-95 % {st['p5'] * 1e3:.6g} .. {st['p95'] * 1e3:.6g}") in out
    assert "DMTModulus (Retrace) [Arb]" in out and "Adhesion (Retrace) [V]" in out


def _crop(scan, rows, cols):
    return Scan(np.array(scan.heights[rows, cols]), scan.dx, scan.dy, scan.channel, dict(scan.metadata), scan.source)


def _pull_off(model, x, y, z0):
    """Press in, then retract in 0.005 nm steps: the most tensile load before the contact breaks."""
    model.reset()
    for d in np.linspace(-1e-9, 2e-9, 61):
        model.step((x, y, z0 - d))
    loads, points = [], []
    for d in np.arange(2e-9, -15e-9, -0.005e-9):
        t = model.step((x, y, z0 - d))
        if t.md_status == 2:
            break
        loads.append(t.load)
        points.append(t.point)
    i = int(np.argmin(loads))
    return loads[i], points[i]


def test_the_stiffest_and_the_softest_decile_feel_different(spm):
    """On a 256-pixel window smoothed over R/2 (as the demo): at one load the soft spot indents
    several times deeper, and each spot's indentation and pull-off are Maugis-Dugdale's of the
    local E* and w at the contact point."""
    from arsurf.demo import pick_spots

    rows, cols = slice(384, 640), slice(384, 640)
    height = level(_crop(load_scan(spm), rows, cols), "plane")
    chans = {role: _crop(load_scan(spm, channel=name), rows, cols)
             for role, name in (("modulus", "DMTModulus"), ("adhesion", "Adhesion"))}
    conv = MaterialConversion(R, **STATED)
    m = build_material_map(height, chans, conv, sigma=0.5 * R)
    model = ARModel(fit_surface(height), R, m.contact_law(), Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27),
                    material=m)
    spots = pick_spots(m, height, R)
    e = m.fields["reduced_modulus"].pixels
    lo, hi = np.percentile(e, [10, 90])
    load = 2e-9
    feel = {}
    for name in ("soft", "stiff"):
        x, y = spots[name]
        assert (m.reduced_modulus(x, y) <= lo) if name == "soft" else (m.reduced_modulus(x, y) >= hi)
        z0 = float(model.surface.evaluate(x, y)[2]) + R
        t = ref_tick_at_load(model, x, y, z0, load, hi=6e-9, iterations=60)
        ex, wx = m.reduced_modulus(*t.point[:2]), m.work_of_adhesion(*t.point[:2])
        md = MaugisDugdale(R, ex, wx, wx / conv.dugdale_range)
        assert t.load == pytest.approx(load, rel=1e-6)
        assert t.depth == pytest.approx(md.depth(load), rel=1e-6)       # MD of the local law
        p, point = _pull_off(model, x, y, z0)
        ep, wp = m.reduced_modulus(*point[:2]), m.work_of_adhesion(*point[:2])
        assert p == pytest.approx(MaugisDugdale(R, ep, wp, wp / conv.dugdale_range).pull_off_force(), rel=0.02)
        feel[name] = (t.depth, p)
    assert feel["soft"][0] > 2.0 * feel["stiff"][0]                     # the soft decile indents far deeper
    assert abs(feel["soft"][1] - feel["stiff"][1]) > 0.2 * max(abs(feel["soft"][1]), abs(feel["stiff"][1]))
