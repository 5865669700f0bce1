"""The 3D views follow the 2D figures' conventions (tests/replay/test_figures.py): the same colour map,
colour limits at the 1st/99th percentiles of the heights shown (computed once per scan), a colour bar
naming its unit with round ticks (no "-0.0"), a scale bar of a round length between a tenth and a
quarter of the width, the vertical exaggeration stated on the picture, the size asked for, and no
HUD box over the scene in saved pictures. Rendered offscreen (skipped only without OpenGL)."""
from __future__ import annotations

import re

import numpy as np
import pytest

from arsurf._figure_style import HEIGHT_CMAP, PERCENTILES, robust_limits
from arsurf.spline.surface import BSplineSurface
from arsurf_viewer.state import SceneState

pytest.importorskip("pyvista", reason="the 3D views need pyvista (pip install 'arsurf[viewer]')")


def _mantissa(x: float) -> int:
    """The leading digit of a round number (1, 2 or 5 for 1-2-5 steps)."""
    m = x / 10.0 ** np.floor(np.log10(x) + 1e-9)
    return int(round(m)) if abs(m - round(m)) < 1e-6 else -1


def check_view(view, png) -> None:
    """What tests/replay/test_figures.py checks on a 2D map, on a 3D view and the PNG it saved."""
    from PIL import Image

    rest_nm = view._rest_points[..., 2]
    lo, hi = view._mapper.scalar_range
    assert (lo, hi) == pytest.approx(tuple(np.percentile(rest_nm, PERCENTILES)), rel=1e-12, abs=1e-12)
    assert view._mapper.lookup_table.cmap.name == HEIGHT_CMAP
    bar = view.scalar_bar
    assert bar.GetTitle() == "height (nm)" and bar.GetUseCustomLabels()
    labels = view._bar_labels
    ticks = [bar.GetCustomLabels().GetValue(i) for i in range(bar.GetCustomLabels().GetNumberOfTuples())]
    assert 2 <= len(ticks) <= 6 and all(lo <= v <= hi for v in ticks)
    for text, value in zip(labels, ticks):
        assert re.fullmatch(r"-?\d+(\.\d+)?", text) and not re.fullmatch(r"-0(\.0*)?", text), labels
        assert float(text) == pytest.approx(value) and bar.GetLabelFormat() % value == text
    step = np.diff(ticks)
    assert np.allclose(step, step[0]) and _mantissa(step[0]) in (1, 2, 5)
    # the scale bar: 1, 2 or 5 x 10^k nm, a tenth to a quarter of the width, its length on the caption
    (u0, u1), _ = view.surface.domain
    width = (u1 - u0) * 1e9
    length = view.scale_bar_nm
    assert _mantissa(length) in (1, 2, 5)
    assert 0.1 * width <= length <= 0.25 * width
    unit = f"{length / 1000:g} µm" if length >= 1000 else f"{length:g} nm"
    assert view._scale_actors[1].GetInput() == unit
    caption = view.caption_actor.GetInput()
    assert f"scale bar {unit}" in caption and "vertical exaggeration 1x" in caption
    assert all(a.GetVisibility() for a in view._scale_actors)
    assert not view.hud_actor.GetVisibility()  # a saved picture: no HUD box over the scene
    image = Image.open(png)
    assert image.size == tuple(view.plotter.window_size)


def _real_surface(path):
    import arsurf

    scan = arsurf.level(arsurf.load_scan(path), "plane")
    return arsurf.fit_surface(scan, control_shape=(96, 96))


@pytest.mark.viewer
def test_a_scratch_does_not_wash_out_a_real_scan(gl, real_scans_dir, tmp_path):
    """Veeco_20160622.003 has a deep scratch: limits from the extremes put the sample at the top of
    the colour map (cream); the 1-99 % limits spread it over the map."""
    from arsurf_viewer import SurfaceView

    surface = _real_surface(real_scans_dir / "Veeco_20160622.003")
    view = SurfaceView(surface, off_screen=True, window_size=(700, 500), anti_aliasing=None)
    try:
        (u0, u1), (v0, v1) = surface.domain
        x, y = 0.5 * (u0 + u1), 0.5 * (v0 + v1)
        view.update(SceneState(surface, (x, y, float(surface.evaluate(x, y)[2]) + 30e-9), 20e-9, force=(0, 0, 2e-9)))
        png = tmp_path / "veeco.png"
        img = view.screenshot(png, dpi=300)
        check_view(view, png)
        from PIL import Image

        assert Image.open(png).info["dpi"] == pytest.approx((300, 300), abs=0.01)
        rest = view._rest_points[..., 2]
        lo, hi = view._mapper.scalar_range
        assert rest.max() - rest.min() > 1.5 * (hi - lo)  # the scratch and spikes: outside the limits
        assert 0.3 < (np.median(rest) - lo) / (hi - lo) < 0.7  # the sample mid-map, not at its cream top
        cream = (img[..., 0] > 235) & (img[..., 1] > 215) & (img[..., 2] > 150)
        assert cream.mean() < 0.03
    finally:
        view.close()


@pytest.mark.viewer
def test_limits_are_set_once_per_scan_and_the_hud_is_kept_on_request(gl, tmp_path):
    from arsurf_viewer import SurfaceView

    x = np.linspace(0.0, 300e-9, 40)
    z = 4e-9 * np.sin(x[:, None] / 40e-9) * np.cos(x[None, :] / 55e-9)
    z[20, 20] = -60e-9  # one pit: outside the 1-99 % limits
    surface = BSplineSurface.from_heights(z, (0.0, 300e-9), (0.0, 300e-9))
    view = SurfaceView(surface, off_screen=True, window_size=(480, 360), anti_aliasing=None)
    try:
        clim = view._mapper.scalar_range
        assert clim == pytest.approx(robust_limits(view._rest_points[..., 2]))
        ctrl = surface.kernel_arrays()[0]
        ctrl[10:14, 10:14, 2] -= 2e-9  # a dent: the height limits stay those of the scan
        view.update(SceneState(surface, (150e-9, 150e-9, 30e-9), 20e-9))
        assert view._mapper.scalar_range == clim
        view.screenshot(tmp_path / "v.png")
        check_view(view, tmp_path / "v.png")
    finally:
        view.close()
    kept = SurfaceView(surface, off_screen=True, window_size=(200, 150), anti_aliasing=None, layers={"hud": True})
    try:
        assert kept.hud_actor.GetVisibility()
    finally:
        kept.close()


def test_view_size_option_is_checked(capsys):
    from arsurf.cli import main

    for bad in ("960", "10x10", "axb", "100000x100"):
        with pytest.raises(SystemExit) as exc:
            main(["view", "--size", bad])
        assert exc.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert "--size" in err[-1] and "WIDTHxHEIGHT" in err[-1]
