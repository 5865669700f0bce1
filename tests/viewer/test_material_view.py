"""The viewer colours the surface by the material map (E*, w, the instrument's own maps) with a
colour bar in the field's unit. Rendering is marked ``viewer`` (skipped only without OpenGL)."""
from __future__ import annotations

import numpy as np
import pytest

from arsurf.contact.material_conversion import MaterialConversion
from arsurf.contact.material_map import build_material_map
from arsurf.errors import ViewerError
from arsurf.scan.scan import Scan
from arsurf.spline.fit import fit_surface

H = 4e-9
N = 40


def _material():
    x = np.arange(N) * H
    es = np.where(x < N * H / 2, 0.1e9, 10e9) * np.ones((N, 1))           # soft left, stiff right (100x)
    force = np.where(np.arange(N)[:, None] < N // 2, 1e-9, 6e-9) * np.ones((1, N))   # sticky top half
    deform = np.where(x < N * H / 2, 3.0, 0.5) * np.ones((N, 1))         # an uncalibrated channel, in V
    chans = {"modulus": Scan(es, H, H, "DMTModulus", {"z_unit": "Pa"}),
             "adhesion": Scan(force, H, H, "Adhesion", {"z_unit": "N"}),
             "deformation": Scan(deform, H, H, "Deformation", {"z_unit": "V"})}
    height = Scan(np.zeros((N, N)), H, H)
    return height, build_material_map(height, chans, MaterialConversion(10e-9), sigma=2e-9)


def test_material_colours_need_a_map():
    pytest.importorskip("pyvista")
    from arsurf_viewer import SurfaceView

    height, m = _material()
    with pytest.raises(ViewerError, match="needs the sample's material map"):
        SurfaceView(fit_surface(height), color_by="modulus", off_screen=True)
    with pytest.raises(ViewerError, match="no dissipation field"):
        SurfaceView(fit_surface(height), color_by="dissipation", material=m, off_screen=True)


@pytest.mark.viewer
def test_the_surface_shows_stiff_and_soft_halves_with_a_colour_bar_in_the_unit(gl):
    from arsurf_viewer import SurfaceView

    height, m = _material()
    s = fit_surface(height)
    view = SurfaceView(s, material=m, color_by="modulus", off_screen=True, window_size=(400, 300),
                       anti_aliasing=None, camera="top", layers={"hud": False})
    try:
        img = view.screenshot()
        assert view.scalar_bar.GetTitle() == "E* (GPa)" and view._mapper.lookup_table.log_scale
        # the legend says what the map means: convention, Poisson ratio and source, cross-check, masks
        legend = view.legend_actor.GetInput()
        assert view.legend_actor.GetVisibility() and legend == "\n".join(m.describe())
        assert legend.startswith("rigid-tip DMT fit, same probe: E* = E_s/(1 - nu_s^2)\nnu_s 0.3 (default")
        assert "no log channel to compare" in legend and "modulus masked 0.00%" in legend
        lo, hi = view._mapper.scalar_range
        assert lo == pytest.approx(float(m.reduced_modulus(0.0, 0.0)) * 1e-9, rel=1e-9)
        assert hi == pytest.approx(float(m.reduced_modulus((N - 1) * H, 0.0)) * 1e-9, rel=1e-9)
        # soft (left) and stiff (right) quarters of the surface render in different colours
        def colour(image, x, y):
            r, c = (int(round(v)) for v in view.world_to_pixel([x, y, 0.0]))
            return image[r - 3:r + 4, c - 3:c + 4].reshape(-1, 3).mean(axis=0)

        q1, q3 = 0.25 * N * H, 0.75 * N * H
        assert np.abs(colour(img, q1, q1) - colour(img, q3, q1)).sum() > 150    # soft | stiff
        assert np.abs(colour(img, q1, q1) - colour(img, q1, q3)).sum() < 15     # uniform along y
        view.set_color_by("adhesion")
        assert view.scalar_bar.GetTitle() == "w (mJ/m^2)" and not view._mapper.lookup_table.log_scale
        img2 = view.screenshot()
        assert np.abs(colour(img2, q1, q1) - colour(img2, q1, q3)).sum() > 150  # sticky | not sticky
        view.set_color_by("sample_deformation")
        assert view.scalar_bar.GetTitle() == "sample deformation (V)"   # uncalibrated: the channel's unit
        view.set_color_by("height")
        assert not view.legend_actor.GetVisibility()                    # the legend belongs to the map
    finally:
        view.close()


@pytest.mark.viewer
def test_the_c_key_cycles_through_the_material_colourings(gl):
    from arsurf_viewer import SurfaceView
    from arsurf_viewer.interactive import StylusController

    height, m = _material()
    s = fit_surface(height)
    view = SurfaceView(s, material=m, off_screen=True, window_size=(200, 150), anti_aliasing=None)
    try:
        assert view.color_modes == ["height", "deformation", "modulus", "adhesion", "sample_deformation"]
        ctl = StylusController(s, (80e-9, 80e-9, 30e-9), view=view)
        seen = [ctl.handle_key("c") for _ in range(5)]
        assert seen == ["colour by deformation", "colour by modulus", "colour by adhesion",
                        "colour by sample_deformation", "colour by height"]
    finally:
        view.close()


@pytest.mark.slow
@pytest.mark.viewer
def test_arsurf_view_material_renders_the_qnm_file_by_modulus(gl, tmp_path):
    from arsurf.cli import main
    from tests.support.real_scans import real_scan_path

    spm = real_scan_path("sample_0.spm")
    out = tmp_path / "view"
    assert main(["view", str(spm), "--material", "--color-by", "modulus", "--frames", "4", "--out", str(out),
                 "--tip-radius-nm", "5", "--modulus-scale", "1.7e10", "--deflection-sensitivity-nm-per-v", "50",
                 "--spring-constant", "40"]) == 0
    assert len(list(out.glob("frame_*.png"))) == 4
    assert main(["view", str(spm), "--material", "--frames", "4", "--out", str(out)]) == 2   # Arb refused
