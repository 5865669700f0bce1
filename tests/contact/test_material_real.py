"""Material maps on the real PeakForce QNM file sample_0.spm (../shared/scans-real): its DMTModulus
is in Arb and its Adhesion in volts of deflection, so every conversion is stated here; the
statistics agree with the channel values through those conversions (E* the fit's own, nu_s from
the header, the pixels where DMTModulus and LogDMTModulus disagree masked), the passivity bound
covers the map's deepest adhesive well, and the model feels the stiffest and the softest decile
differently (indentation at one load, pull-off)."""
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
from tests.support.reference import ref_load_depth, ref_radius_from_depth, ref_tick_at_load

pytestmark = pytest.mark.realscan

R = 5e-9                                  # the file's own "Tip Radius: 5" (nm)
#: the stated conversions (assumptions: the file leaves both channels uncalibrated)
STATED = dict(modulus_scale=1.7e10, deflection_sensitivity=50e-9, spring_constant=40.0)


@pytest.fixture(scope="module")
def spm():
    return real_scan_path("sample_0.spm")


@pytest.fixture(scope="module")
def channels(spm):
    """The two modulus channels as arsurf reads them (Arb; the log one decoded, 10**value)."""
    return (np.asarray(load_scan(spm, channel="DMTModulus").heights),
            np.asarray(load_scan(spm, channel="LogDMTModulus").heights))


@pytest.fixture(scope="module")
def default_map(spm):
    """The map as built by default (cross-check: mask), with the stated conversions."""
    return material_map_from_file(spm, MaterialConversion(R, **STATED))


def test_uncalibrated_channels_are_refused_without_their_conversion(spm):
    with pytest.raises(MaterialMapError, match="DMTModulus.*'Arb', not Pa.*modulus_scale"):
        material_map_from_file(spm, MaterialConversion(R))
    with pytest.raises(MaterialMapError, match="volts of photodiode deflection"):
        material_map_from_file(spm, MaterialConversion(R, modulus_scale=1e10))


def _disagree(lin, log, lsb):
    """The cross-check, written out: |E_lin - E_log| > 1 LSB + 1 % of E_log."""
    return np.abs(lin - log) > lsb + 0.01 * log


def _independent_statistics(spm, conv):
    """E* and w of the unmasked pixels, recomputed here from the raw channels and the stated
    conversion (NanoScope full scale from the Z scale, the two modulus channels compared, robust
    log outliers, E* = E_s / (1 - 0.3^2) with the header's ratio, DMT pull-off law)."""
    mod = load_scan(spm, channel="DMTModulus")
    adh = load_scan(spm, channel="Adhesion")
    v = mod.heights
    full = mod.metadata["z_per_lsb"] * (2.0 ** 31 - 1)
    ok = np.isfinite(v) & (v > 0) & (np.abs(v) < full * (1 - 1e-9))
    ok &= ~_disagree(v, load_scan(spm, channel="LogDMTModulus").heights, mod.metadata["z_per_lsb"])
    lv = np.log(np.where(ok, v * conv.modulus_scale, 1.0))
    med = np.median(lv[ok])
    mad = 1.4826 * np.median(np.abs(lv[ok] - med))
    ok &= np.abs(lv - med) <= conv.outlier_mads * mad
    es = v[ok] * conv.modulus_scale
    e_star = es / (1 - 0.3 ** 2)      # the header's Sample Poisson's Ratio: 0.3
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
    assert m.conversion.sample_poisson == 0.3 and "header" in m.processing["sample_poisson_source"]
    # arsurf info --material prints the same figures, in GPa and mJ/m^2
    assert main(["info", str(spm), "--material", "--tip-radius-nm", "5", "--regime", "dmt", "--adhesion-floor-nn", "1",
                 "--modulus-scale", "1.7e10", "--deflection-sensitivity-nm-per-v", "50", "--spring-constant", "40"]) == 0
    out = capsys.readouterr().out
    st = m.statistics["reduced_modulus"]
    assert (f"median {st['median'] / 1e9:.6g}, 5-95 % {st['p5'] / 1e9:.6g} .. {st['p95'] / 1e9:.6g}") in out
    st = m.statistics["work_of_adhesion"]
    assert (f"median {st['median'] * 1e3:.6g}, 5-95 % {st['p5'] * 1e3:.6g} .. {st['p95'] * 1e3:.6g}") in out
    assert "DMTModulus (Retrace) [Arb]" in out and "Adhesion (Retrace) [V]" in out
    # and what the map means: the convention, nu_s from the header, the cross-check, masks by reason
    assert "rigid-tip DMT fit, same probe: E* = E_s/(1 - nu_s^2)" in out
    assert "nu_s 0.3 (file header (Sample Poisson's Ratio))" in out
    disagree = m.processing["cross_check"]["disagreeing_fraction"]
    assert f"DMTModulus (Retrace) vs LogDMTModulus (Retrace): {disagree:.2%} disagree (masked)" in out
    assert f"channels disagree {disagree:.2%}" in out and "saturated 0.06%" in out


def test_the_two_modulus_channels_disagree_and_none_of_those_pixels_stays_unmasked(spm, channels, default_map):
    """DMTModulus = 16^k x 10^LogDMTModulus, k = 1..5, on ~17 % of sample_0.spm (pySPM reads the
    same: it is in the file). The map reports the fraction, masks every such pixel (filled from
    its neighbours), and nothing of the linear channel's top decile survives at its 16^k value."""
    lin, log = channels
    lsb = load_scan(spm, channel="DMTModulus").metadata["z_per_lsb"]
    with np.errstate(divide="ignore", invalid="ignore"):
        k = np.rint(np.log(lin / log) / np.log(16.0))
    counts = {int(j): int((k == j).sum()) for j in range(1, 6)}
    assert counts == {1: 149431, 2: 25692, 3: 4458, 4: 642, 5: 14}          # the census
    pyspm = pytest.importorskip("pySPM")
    b = pyspm.Bruker(str(spm))
    plin, plog = b.get_channel("DMTModulus").pixels, 10.0 ** b.get_channel("LogDMTModulus").pixels
    with np.errstate(divide="ignore", invalid="ignore"):
        pk = np.rint(np.log(plin / plog) / np.log(16.0))
    assert {j: int((pk == j).sum()) for j in range(1, 6)} == counts        # pySPM: the same values
    m = default_map
    full = lsb * (2.0 ** 31 - 1)
    usable = (lin != 0) & (lin < full * (1 - 1e-9))
    disagree = usable & _disagree(lin, log, lsb)
    cross = m.processing["cross_check"]
    assert cross["disagreeing_fraction"] == disagree.sum() / lin.size
    assert 0.17 < cross["disagreeing_fraction"] < 0.175 and cross["channel"] == "LogDMTModulus (Retrace)"
    assert (k[usable] >= 1).sum() <= disagree.sum()                        # every 16^k pixel is among them
    e_lin = lin * STATED["modulus_scale"] / (1 - 0.3 ** 2)
    pix = m.fields["reduced_modulus"].pixels
    factor = disagree & (k >= 1)
    assert not np.isclose(pix[disagree], e_lin[disagree], rtol=1e-9, atol=0.0).any()  # none kept at its value
    assert np.median(np.abs(np.log(pix[factor] / e_lin[factor]))) > 2.0       # filled: ~16x below, or more
    keep = usable & ~disagree                 # the rest: E* = E_s / (1 - nu_s^2), nu_s = 0.3 from the header
    assert np.isclose(pix[keep], e_lin[keep], rtol=1e-12, atol=0.0).mean() > 0.998   # (0.15 % outliers)
    assert m.statistics["reduced_modulus"]["pixels"] == round((1 - m.masked["modulus"]["masked"]) * lin.size)
    top = usable & (lin >= np.percentile(lin[usable], 90))
    assert factor[top].mean() > 0.99                                       # the linear top decile: those pixels
    # the 95th percentile of E* no longer rests on them: far below the unchecked channel's
    assert m.statistics["reduced_modulus"]["p95"] < 0.2 * np.percentile(e_lin[usable], 95)


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


def _others_bound(model, law):
    """The most the contacts of the table other than the closest can carry (N): each its weight
    times the larger of ``law``'s load at its depth and its pull-off force (the tick applies the
    law where the tip touches, the material map's there, to every contact under the tip)."""
    from arsurf.contact import multi_contact as mc
    from arsurf.model import S_CONTACTS

    st, total = model.state, 0.0
    for i in range(1, int(st[S_CONTACTS + mc.T_COUNT])):
        r = S_CONTACTS + mc.T_ROWS + i * mc.C_SIZE
        total += st[r + mc.C_WEIGHT] * max(abs(float(law.load(st[r + mc.C_DEPTH]))), abs(law.pull_off_force()))
    return total


def test_the_stiffest_and_the_softest_decile_feel_different(spm):
    """On a 256-pixel window smoothed over R/2 (as the demo): at one load the soft spot indents
    several times deeper, each spot's indentation is Maugis-Dugdale's of the local E* and w at the
    contact point (to within what the other contacts under the tip can carry), and its pull-off that law's,
    or up to a tenth more where neighbouring asperities are within the adhesion range."""
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
        # MD of the local law, to within what the other contacts under the tip carry: each counts with
        # at most its weight times the law's load at its depth (or pull-off, in tension). The stiff spot
        # has ten minima in reach, merged into its contact or held by adhesion: one, 0.13 nm short of
        # touching, pulls at weight 0.2 (the others can carry 1.4 nN at most), and the spot's own
        # contact carries 3.1 nN of the 2
        others = _others_bound(model, md)
        assert abs(float(md.load(t.depth)) - load) <= others + 1e-3 * load
        assert others <= 0.75 * load  # the spot's own law still carries the most of it
        # and Maugis' equations as printed (tests/support/reference.py), at the local E*, w: the law's
        # load at the tick's depth
        k = 4.0 * ex / 3.0
        lam = 2.0 * (wx / conv.dugdale_range) * (R / (math.pi * wx * k * k)) ** (1.0 / 3.0)
        depth_scale = (math.pi ** 2 * wx ** 2 * R / k ** 2) ** (1.0 / 3.0)
        a_bar = ref_radius_from_depth(t.depth / depth_scale, lam)
        assert float(md.load(t.depth)) == pytest.approx(ref_load_depth(a_bar, lam)[0] * math.pi * wx * R, rel=1e-6)
        p, point = _pull_off(model, x, y, z0)
        ep, wp = m.reduced_modulus(*point[:2]), m.work_of_adhesion(*point[:2])
        single = MaugisDugdale(R, ep, wp, wp / conv.dugdale_range).pull_off_force()  # < 0
        # the spot's own contact pulls off at its law's force; the scan's asperities around it within
        # the adhesion range (found since the net is scanned for minima) add their partly merged
        # adhesion: at most a tenth more here
        assert 0.98 * single >= p >= 1.10 * single
        feel[name] = (t.depth, p)
    assert feel["soft"][0] > 2.0 * feel["stiff"][0]                     # the soft decile indents far deeper
    assert abs(feel["soft"][1] - feel["stiff"][1]) > 0.2 * max(abs(feel["soft"][1]), abs(feel["stiff"][1]))


def _well(law, kc):
    """E0 of one Maugis-Dugdale law (ARModel.adhesion_energy's formula, from the law's own methods)."""
    pc = abs(law.pull_off_force())
    return pc * (float(law.depth(0.0)) - min(law.jump_out_depth(), law.jump_in_depth()) + pc / kc)


@pytest.mark.parametrize("kc", [math.inf, 5.0])
def test_the_passivity_bound_covers_the_deepest_adhesive_well_of_the_map(spm, default_map, kc):
    """The passivity reserve E0 (ARModel.adhesion_energy) with the real map is at least the
    well of every pixel's own law (exact MaugisDugdale at the 1000 pixels of largest
    w R (depth scale + h0), the DMT-like estimate), far beyond the median law's, which alone was
    the reserve before."""
    m = default_map
    height = level(load_scan(spm), "plane")
    model = ARModel(fit_surface(height), R, m.contact_law(), Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27),
                    material=m, coupling_stiffness=kc)
    e0 = model.adhesion_energy()
    e = m.fields["reduced_modulus"].pixels.ravel()
    w = m.fields["work_of_adhesion"].pixels.ravel()
    h0 = m.conversion.dugdale_range
    scale = (math.pi ** 2 * w ** 2 * R / (4 * e / 3) ** 2) ** (1 / 3)
    candidates = np.argsort(w * R * (scale + h0))[-1000:]
    wells = [_well(MaugisDugdale(R, e[i], w[i], w[i] / h0), kc) for i in candidates]
    deepest = max(wells)
    assert e0 >= deepest
    assert e0 < 3.0 * deepest                     # a bound of the map's wells (and between its pixels), not more
    assert deepest > 10.0 * _well(m.contact_law(), kc)


def test_the_docs_page_runs_as_printed(default_map, capsys, monkeypatch):
    """docs/materials.rst: its code block builds the map tested here (same hash) and prints the legend."""
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    text = (root / "docs" / "materials.rst").read_text(encoding="utf-8")
    block = re.search(r"\.\. code-block:: python\n\n((?:   .*\n|\n)+)", text).group(1)
    code = "\n".join(line[3:] for line in block.splitlines())
    monkeypatch.chdir(root)
    namespace: dict = {}
    exec(compile(code, "docs/materials.rst", "exec"), namespace)
    m = namespace["m"]
    assert m.sha256 == default_map.sha256
    assert capsys.readouterr().out.splitlines() == m.describe()
    assert round(m.summary()["cross_check"]["disagreeing_fraction"], 4) == 0.1717      # as the page says
