"""Notebook display (arsurf._display): Scan and BSplineSurface show their size, pixels, units, channel
and z range in HTML and a thumbnail PNG whose colours follow the data; untrusted text is escaped."""
from __future__ import annotations

import html
import io
import re
import struct

import matplotlib.image as mpimg
import numpy as np
import pytest

from arsurf._display import THUMB_PIXELS, _block_mean, card, map_png, quantity, robust_limits
from arsurf.contact.deformation import Deformer
from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.contact.projection import collide
from arsurf.scan.scan import Scan
from arsurf.spline.fit import fit_surface


def _png_size(data: bytes) -> tuple[int, int]:
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def _rows(text: str) -> dict[str, str]:
    return {html.unescape(k): html.unescape(v) for k, v in re.findall(r"<th[^>]*>(.*?)</th><td[^>]*>(.*?)</td>", text)}


def _image(data: bytes) -> np.ndarray:
    return mpimg.imread(io.BytesIO(data), format="png")[..., :3]


@pytest.mark.parametrize("value, unit, text", [
    (1.25e-8, "m", "12.5 nm"), (1.024e-6, "m", "1.024 µm"), (3.2e-9, "N", "3.2 nN"), (2e9, "Pa", "2 GPa"),
    (0.5, "rad", "0.5 rad"), (1000.0, "Hz", "1 kHz"), (0.0, "m", "0 m"), (-4e-12, "m", "-4 pm"),
    (float("nan"), "m", "n/a"), (None, "N", "n/a"), (0.1, "J/m^2", "0.1 J/m^2"), (999.96e-9, "m", "1 µm"),
])
def test_quantities_carry_an_si_prefix_and_their_unit(value, unit, text):
    assert quantity(value, unit) == text


def test_robust_limits_ignore_a_speck():
    z = np.zeros((50, 50))
    z[:, 25:] = 10e-9
    z[3, 3] = 1e-6  # one pixel 100x higher than the rest
    lo, hi = robust_limits(z)
    assert (lo, hi) == (0.0, 10e-9)
    assert robust_limits(np.full((3, 3), 2.0)) == (1.5, 2.5)  # flat: a unit band around it
    assert robust_limits(np.full((3, 3), np.nan)) == (0.0, 1.0)


def test_block_mean_bounds_the_thumbnail_and_keeps_nan_blocks():
    z = np.arange(1000 * 450, dtype=float).reshape(450, 1000)
    z[:10, :10] = np.nan
    small = _block_mean(z, THUMB_PIXELS)
    assert max(small.shape) <= THUMB_PIXELS and small.shape == (90, 200)
    assert np.isnan(small[:2, :2]).all() and np.isfinite(small[2:]).all() and np.isfinite(small[:, 2:]).all()
    assert small[2, 3] == pytest.approx(z[10:15, 15:20].mean())
    assert _block_mean(z[:40, :40], THUMB_PIXELS) is not None and _block_mean(z[:40, :40], 200).shape == (40, 40)


def _step_scan(nx=120, ny=80, channel="Height") -> Scan:
    """Left half 0 nm, right half 10 nm; 2 nm x 3 nm pixels; 5 NaN pixels."""
    h = np.zeros((ny, nx))
    h[:, nx // 2:] = 10e-9
    h[0, :5] = np.nan
    return Scan(h, dx=2e-9, dy=3e-9, channel=channel, metadata={"format": "npz"}, source="scan.npz")


def test_scan_html_names_pixels_sizes_units_channel_and_z_range():
    rows = _rows(_step_scan()._repr_html_())
    assert rows["channel"] == "Height (m)"
    assert rows["pixels"] == "120 x 80 px"
    assert rows["pixel size"] == "2 nm x 3 nm"
    assert rows["scan size"] == "240 nm x 240 nm"
    assert rows["z range"] == "10 nm" and rows["z min / max"] == "0 m / 10 nm"
    assert rows["missing pixels"] == "5 (NaN)" and rows["format"] == "npz" and rows["source"] == "scan.npz"


def test_scan_html_escapes_text_from_files():
    html = _step_scan(channel="<script>alert(1)</script>")._repr_html_()
    assert "<script>" not in html and "&lt;script&gt;alert(1)&lt;/script&gt;" in html


def test_scan_html_shows_the_processing_history():
    from arsurf.scan.level import level
    from arsurf.scan.smooth import smooth

    scan = smooth(level(_step_scan(), "plane"), 2e-9)
    assert _rows(scan._repr_html_())["processing"] == "level (plane) -> smooth (gaussian)"


def test_scan_thumbnail_colours_follow_the_heights():
    data = _step_scan()._repr_png_()
    w, h = _png_size(data)
    assert (w, h) == (288, 216)
    img = _image(data)
    # viridis: 0 nm is dark purple, 10 nm yellow; the low half of the map lies left of the high half
    purple = np.argwhere(np.abs(img - [0.267, 0.005, 0.329]).max(axis=2) < 0.03)
    yellow = np.argwhere(np.abs(img - [0.993, 0.906, 0.144]).max(axis=2) < 0.03)
    assert len(purple) > 3000 and len(yellow) > 3000  # each half of the map (and the colour bar's end)
    assert np.median(purple[:, 1]) < np.median(yellow[:, 1]) - 40
    assert _step_scan()._repr_png_() == data  # same data, same bytes (no time or version in the PNG)


def test_a_large_scan_gives_a_thumbnail_of_the_same_size():
    scan = Scan(np.random.default_rng(1).normal(size=(1500, 1100)) * 1e-9, dx=1e-9, dy=1e-9)
    assert _png_size(scan._repr_png_()) == (288, 216)


def test_other_channels_show_their_own_unit():
    scan = Scan(np.linspace(0, 2.0, 20).reshape(4, 5), dx=1e-9, dy=1e-9, channel="Phase",
                metadata={"z_unit": "deg"})
    rows = _rows(scan._repr_html_())
    assert rows["channel"] == "Phase (deg)" and rows["z range"] == "2 deg"


def test_surface_html_and_thumbnail_show_the_net_and_the_dent():
    from arsurf.scan.synthetic import sinusoid

    scan = sinusoid(shape=(40, 40), pixel=2e-9, amplitude=5e-9, period=39e-9)
    surface = fit_surface(scan)
    rest_rows = _rows(surface._repr_html_())
    assert rest_rows["control points"] == "42 x 42" and rest_rows["deformed"] == "no"
    assert rest_rows["domain (x, y)"] == "78 nm x 78 nm" and rest_rows["knot spacing"] == "2 nm x 2 nm"
    z_range, rest = rest_rows["z range"].split(" nm ")
    assert float(z_range) == pytest.approx(np.ptp(scan.heights) * 1e9, rel=0.02)
    assert rest == "(sampled on 200 x 200 points)"
    before = _image(surface._repr_png_())
    # press a 10 nm tip 2 nm into the low plateau: the dent is outlined in white over the map
    top = float(surface.evaluate(40e-9, 40e-9)[2])
    centre = (40e-9, 40e-9, top + 10e-9 - 2e-9)
    contact = collide(surface, center=centre, radius=10e-9)
    md = MaugisDugdale(10e-9, 50e9, 0.1)
    Deformer(surface).apply(centre, 10e-9, contact.normal, md.contact_radius(depth=contact.depth))
    rows = _rows(surface._repr_html_())
    moved = int(rows["deformed"].split()[0])
    assert moved == int(np.count_nonzero(np.linalg.norm(surface.control_points - surface.rest_control_points,
                                                        axis=2)))
    assert moved > 0 and "at most" in rows["deformed"]
    after = _image(surface._repr_png_())
    changed = np.argwhere(np.abs(after - before).max(axis=2) > 0.2)  # the outline, and only there
    # the outline spans the moved points: the contact disc and the elastic profile around it (the
    # dent's rim is the contact radius; outside it the surface follows the MD stresses' field)
    assert len(changed) > 50 and np.ptp(changed, axis=0).max() < 80
    whitened = after[tuple(changed.T)].min(axis=1) > 0.75  # the outline, white over the (dented) map
    assert whitened.sum() > 30 and (before[tuple(changed.T)].min(axis=1) > 0.75).sum() < whitened.sum() / 3


def test_card_escapes_its_title_and_embeds_the_png():
    html = card("A<b>", [("k&", "<v>")], b"\x89PNG")
    assert "A&lt;b&gt;" in html and "k&amp;" in html and "&lt;v&gt;" in html
    assert "data:image/png;base64,iVBORw==" in html
    assert "<img" not in card("t", [("k", "v")])


def test_map_png_refuses_nothing_it_is_given():
    """A map of NaN only, or a flat one, still draws (empty/flat colour bar), never raises."""
    for z in (np.full((5, 5), np.nan), np.zeros((5, 5))):
        assert _png_size(map_png(z, (0, 4e-9, 0, 4e-9), "m", "height")) == (288, 216)
